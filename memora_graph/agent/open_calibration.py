"""The confidence of an open answer: a logistic calibration over its evidence features.

p(right) = sigmoid(w[kind] + sum_f w[f] * feature_f), with the features each answer carries
(`OpenAnswer.features`: log(1 + support), the answer's share of the cases, its margin over the
runner-up, whether it came from a fallback store, whether the match was exact). The weights live
in `open_calibration.json` next to this module, with the cohort and the command that fitted them:

    memora bench open banks/epic --participants P01,P02,P03 --fit-calibration memora_graph/agent/open_calibration.json

`fit` is plain L2-regularised logistic regression (Newton steps, numpy); `ece` the expected
calibration error over equal-width bins.
"""

from __future__ import annotations

import json
import math
from functools import lru_cache
from pathlib import Path

import numpy as np

CALIBRATION_FILE = Path(__file__).with_name("open_calibration.json")
FEATURES = ("log_support", "share", "margin", "fallback", "exact")
ANSWER_KINDS = ("place", "time", "count", "yesno", "next", "routine", "state", "activity", "actions", "not_in_memory")


@lru_cache(maxsize=4)
def load(path: str = "") -> dict:
    """The fitted weights (an uninformative 0.5 for everything when no file has been fitted)."""
    p = Path(path) if path else CALIBRATION_FILE
    if not p.exists():
        return {"weights": {}, "fitted_on": [], "n": 0}
    data = json.loads(p.read_text())
    if not isinstance(data.get("weights"), dict):
        raise ValueError(f"{p}: 'weights' must be an object of feature -> weight")
    return data


def design_row(kind: str, features: dict[str, float]) -> dict[str, float]:
    row = {f"kind={kind}": 1.0}
    if kind != "not_in_memory":
        row.update({f: float(features.get(f, 0.0)) for f in FEATURES})
    return row


def probability(kind: str, features: dict[str, float], weights: dict[str, float]) -> float:
    z = sum(weights.get(k, 0.0) * v for k, v in design_row(kind, features).items())
    return 1.0 / (1.0 + math.exp(-max(-30.0, min(30.0, z))))


def calibrate(answer) -> float:
    """The probability that `answer` (an OpenAnswer) is right."""
    return round(probability(answer.kind, answer.features, load()["weights"]), 4)


def fit(rows: list[tuple[str, dict[str, float]]], labels: list[bool], l2: float = 1.0, steps: int = 50) -> dict[str, float]:
    """Logistic regression of `labels` on the design rows of (kind, features)."""
    design = [design_row(k, f) for k, f in rows]
    names = sorted({n for r in design for n in r})
    x = np.array([[r.get(n, 0.0) for n in names] for r in design], dtype=float)
    y = np.array(labels, dtype=float)
    w = np.zeros(len(names))
    for _ in range(steps):
        p = 1.0 / (1.0 + np.exp(-np.clip(x @ w, -30, 30)))
        grad = x.T @ (p - y) + l2 * w
        hess = (x * (p * (1 - p))[:, None]).T @ x + l2 * np.eye(len(names))
        step = np.linalg.solve(hess, grad)
        w -= step
        if np.max(np.abs(step)) < 1e-8:
            break
    return {n: round(float(v), 5) for n, v in zip(names, w)}


def ece(probs: list[float], labels: list[bool], bins: int = 10) -> tuple[float, list[dict]]:
    """Expected calibration error and the reliability table (per bin: count, mean p, accuracy)."""
    table, total, err = [], len(probs), 0.0
    for b in range(bins):
        lo, hi = b / bins, (b + 1) / bins
        idx = [i for i, p in enumerate(probs) if (lo <= p < hi) or (b == bins - 1 and p == 1.0)]
        if not idx:
            continue
        conf = sum(probs[i] for i in idx) / len(idx)
        acc = sum(1.0 for i in idx if labels[i]) / len(idx)
        err += len(idx) / total * abs(conf - acc)
        table.append({"bin": f"{lo:.1f}-{hi:.1f}", "n": len(idx), "confidence": round(conf, 3), "accuracy": round(acc, 3)})
    return round(err, 4), table


def write(path: Path, weights: dict[str, float], fitted_on: list[str], n: int, command: str, extra: dict | None = None):
    path.write_text(json.dumps({"about": "Logistic calibration of open answers (memora_graph/agent/open_calibration.py)",
                                "command": command, "fitted_on": fitted_on, "n": n, "features": list(FEATURES),
                                "weights": weights, **(extra or {})}, indent=2) + "\n")
    load.cache_clear()
