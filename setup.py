"""The wheel's bundled files: the schema, the named queries and the bundled data stay in their folders at
the repository root (schema/, queries/, bench/data/) and ship inside the package as memora_graph/_bundled/,
where memora_graph/paths.py finds them with importlib.resources. Everything else is in pyproject.toml."""

from setuptools import find_packages, setup

BUNDLED = {  # package inside the wheel -> folder in the repository
    "memora_graph._bundled.schema": "schema",
    "memora_graph._bundled.queries": "queries",
    "memora_graph._bundled.data": "bench/data",
}

setup(
    packages=find_packages(include=["memora_graph*"]) + list(BUNDLED),
    package_dir=BUNDLED,
    package_data={
        "memora_graph.explore": ["*.html", "*.js", "*.css"],
        "memora_graph.agent": ["open_calibration.json", "calibration.json"],
        **{name: ["**/*"] for name in BUNDLED},
    },
)
