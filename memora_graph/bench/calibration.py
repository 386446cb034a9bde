"""Fitting and checking the reader's confidence (`agent.confidence`) from a run's records.

    memora bench calibrate RUN_DIR --participants P01,P02,P03    # refit memora_graph/agent/calibration.json

Every offline EAM-QA record carries the evidence features the reader computed (`reader_features`)
and, once a calibration is installed, the probability that its answer is right (`confidence`).
`fit` learns a multinomial logistic model (the best option is right / E is right / another option
is) over the features of the chosen participants' records of the memory conditions, with a small L2
penalty, by Newton's method; the threshold on P(best) that decides E is the one that gives the
highest accuracy on those same records. `calibration_summary` is what the report shows for a set
of records: expected calibration error over ten equal-width bins, the reliability diagram's bins,
and accuracy at full, 80% and 50% coverage (the answers kept are the most confident ones).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from memora_graph.agent.confidence import CALIBRATION_FILE, Calibration, feature_vector
from memora_graph.errors import MemoraError

BINS = 10
L2 = 10.0  # ridge on the standardised weights (not the intercepts)
COVERAGES = (1.0, 0.8, 0.5)
FIT_CONDITIONS = ("memora_full", "memora_episodic")  # the reader's own memories


def _outcome(best_letter: str, gold: str) -> int:
    if gold == "E":
        return 1
    return 0 if best_letter == gold else 2


def training_rows(records: list[dict[str, Any]]) -> tuple[list[dict[str, float]], list[int]]:
    """(features, outcome index in OUTCOMES) of each record that carries the reader's features."""
    feats, ys = [], []
    for r in records:
        f = r.get("reader_features")
        if not f or r.get("status") != "ok":
            continue
        feats.append({k: float(v) for k, v in f.items() if k != "best_letter"})
        ys.append(_outcome(f.get("best_letter", ""), r["correct_answer"]))
    return feats, ys


def _softmax_fit(x: np.ndarray, y: np.ndarray, l2: float, iters: int = 50) -> np.ndarray:
    """Weights (2 classes x (1 + features)) of a softmax regression with class 2 as reference,
    by Newton's method on the penalised log-likelihood."""
    n, d = x.shape
    xb = np.hstack([np.ones((n, 1)), x])
    k = 2
    w = np.zeros((k, d + 1))
    penalty = np.full(d + 1, l2)
    penalty[0] = 0.0
    for _ in range(iters):
        logits = np.hstack([xb @ w.T, np.zeros((n, 1))])
        logits -= logits.max(axis=1, keepdims=True)
        p = np.exp(logits)
        p /= p.sum(axis=1, keepdims=True)
        grad = np.concatenate([xb.T @ (p[:, c] - (y == c)) + penalty * w[c] for c in range(k)])
        hess = np.zeros((k * (d + 1), k * (d + 1)))
        for a in range(k):
            for b in range(k):
                wgt = p[:, a] * ((a == b) - p[:, b])
                block = xb.T @ (xb * wgt[:, None])
                if a == b:
                    block += np.diag(penalty)
                hess[a * (d + 1):(a + 1) * (d + 1), b * (d + 1):(b + 1) * (d + 1)] = block
        step = np.linalg.solve(hess + 1e-9 * np.eye(len(grad)), grad)
        w -= step.reshape(k, d + 1)
        if np.abs(step).max() < 1e-8:
            break
    return w


def fit(records: list[dict[str, Any]], l2: float = L2, fitted_on: dict[str, Any] | None = None) -> Calibration:
    feats, ys = training_rows(records)
    if len(ys) < 20:
        raise MemoraError(f"only {len(ys)} records carry the reader's features; a calibration needs a run of the "
                          "offline reader (`memora bench run ...`) with at least 20 EAM-QA items")
    names = sorted({k for f in feats for k in f})
    x = np.array([feature_vector(f, names) for f in feats])
    mean, scale = x.mean(axis=0), x.std(axis=0)
    scale[scale < 1e-9] = 1.0
    w = _softmax_fit((x - mean) / scale, np.array(ys), l2)
    cal = Calibration(names, mean.tolist(), scale.tolist(),
                      {"best": w[0, 1:].tolist(), "E": w[1, 1:].tolist()},
                      {"best": float(w[0, 0]), "E": float(w[1, 0])}, 0.5, dict(fitted_on or {}))
    cal.threshold = best_threshold([cal.probabilities(f)["best"] for f in feats], ys, [forced_e(f) for f in feats])
    cal.fitted_on["n"] = len(ys)
    return cal


def forced_e(f: dict[str, float]) -> bool:
    """Whether the reader answers E whatever the probability: memory holds nothing of the subject,
    or the best option is tied."""
    return f.get("subject_found", 1.0) == 0.0 or f.get("log_windows", 1.0) == 0.0 or f.get("margin", 1.0) == 0.0


def best_threshold(p_best: list[float], outcomes: list[int], forced: list[bool] | None = None) -> float:
    """The threshold on P(best) with the highest accuracy (answer the best option at or above it,
    E below; `forced` items are E regardless); ties go to the middle of the best run of thresholds."""
    grid = np.round(np.arange(0.05, 0.951, 0.01), 2)
    p, y = np.array(p_best), np.array(outcomes)
    if forced is not None:
        p = np.where(np.array(forced, dtype=bool), -1.0, p)
    acc = np.array([np.mean(np.where(p >= t, y == 0, y == 1)) for t in grid])
    top = np.flatnonzero(acc >= acc.max() - 1e-12)
    return float(grid[top[len(top) // 2]])


def save(cal: Calibration, path: str | Path | None = None) -> Path:
    p = Path(path) if path else CALIBRATION_FILE
    data = cal.to_json()
    data["coef"] = {o: [round(v, 6) for v in ws] for o, ws in data["coef"].items()}
    data["intercept"] = {o: round(v, 6) for o, v in data["intercept"].items()}
    data["mean"] = [round(v, 6) for v in data["mean"]]
    data["scale"] = [round(v, 6) for v in data["scale"]]
    tmp = p.with_name(f".{p.name}.tmp")
    tmp.write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
    tmp.replace(p)
    return p


# -- checking ------------------------------------------------------------------------------------


def reliability(conf: list[float], correct: list[bool], bins: int = BINS) -> list[dict[str, float]]:
    """Equal-width bins over [0, 1]: per non-empty bin its count, mean confidence, accuracy."""
    out = []
    c, y = np.array(conf, dtype=float), np.array(correct, dtype=float)
    idx = np.minimum((c * bins).astype(int), bins - 1)
    for b in range(bins):
        m = idx == b
        if m.any():
            out.append({"lo": b / bins, "hi": (b + 1) / bins, "n": int(m.sum()),
                        "confidence": float(c[m].mean()), "accuracy": float(y[m].mean())})
    return out


def ece(conf: list[float], correct: list[bool], bins: int = BINS) -> float | None:
    """Expected calibration error: the count-weighted mean |accuracy - confidence| over the bins."""
    if not conf:
        return None
    n = len(conf)
    return float(sum(b["n"] / n * abs(b["accuracy"] - b["confidence"]) for b in reliability(conf, correct, bins)))


def selective_accuracy(conf: list[float], correct: list[bool], coverage: float) -> float | None:
    """Accuracy over the most confident `coverage` share of the answers."""
    if not conf:
        return None
    k = max(1, int(round(coverage * len(conf))))
    order = np.argsort(-np.array(conf), kind="stable")[:k]
    return float(np.mean(np.array(correct, dtype=float)[order]))


def calibration_summary(records: list[dict[str, Any]]) -> dict[str, Any] | None:
    """ECE, reliability bins and coverage accuracies of the records that carry a confidence."""
    rs = [r for r in records if r.get("confidence") is not None and r.get("status") == "ok"]
    if not rs:
        return None
    conf = [float(r["confidence"]) for r in rs]
    correct = [r["predicted"] == r["correct_answer"] for r in rs]
    return {"n": len(rs), "ece": ece(conf, correct), "reliability": reliability(conf, correct),
            "mean_confidence": float(np.mean(conf)), "accuracy": float(np.mean(correct)),
            "coverage_accuracy": {f"{int(c * 100)}": selective_accuracy(conf, correct, c) for c in COVERAGES}}

