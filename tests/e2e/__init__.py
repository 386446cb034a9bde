"""End-to-end and opt-in groups: trust, video, ray, real_model (a package, so that only tests/, not
tests/e2e/, goes on sys.path: a folder named `ray` there would pass for the Ray package when the
[ray] extra is not installed)."""
