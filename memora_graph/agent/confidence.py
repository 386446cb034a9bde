"""A confidence, not a score: the probability that the reader's answer is right.

The typed reader (`agent.reading`) scores the options against the evidence; those scores rank the
options but do not say how often the best one is right. This module turns the evidence features of
one question (how much of its subject memory holds, how strongly and how clearly the best option is
supported, what kind of question it is) into two probabilities with a multinomial logistic model
over three outcomes: the best option is the right answer, E ("not in memory") is, or another
option is. The reader answers the best option when its probability reaches the threshold, else E;
the answer carries the probability of what it answered.

The model's coefficients are data, not code: `calibration.json` next to this module, fitted on the
calibration cohort's P01-P03 only (P04 held out) with

    memora bench calibrate RUN_DIR --participants P01,P02,P03

from the records of a `memora bench run` (each offline record carries its evidence features).
Without the file (or with an empty one) the reader falls back to the fixed rules it had before.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

CALIBRATION_FILE = Path(__file__).with_name("calibration.json")
OUTCOMES = ("best", "E", "other")  # the best option is right | E is right | another option is
KINDS = ("habit", "preference", "routine", "recall")


def feature_vector(f: dict[str, float], names: list[str]) -> list[float]:
    return [float(f.get(n, 0.0)) for n in names]


@dataclass
class Calibration:
    """Standardised features -> softmax over OUTCOMES (the "other" outcome is the reference)."""

    features: list[str]
    mean: list[float]
    scale: list[float]
    coef: dict[str, list[float]]  # outcome -> weights (features), for "best" and "E"
    intercept: dict[str, float]
    threshold: float  # answer the best option when P(best) >= threshold, else E
    fitted_on: dict[str, Any] = field(default_factory=dict)

    def probabilities(self, f: dict[str, float]) -> dict[str, float]:
        x = [(v - m) / s for v, m, s in zip(feature_vector(f, self.features), self.mean, self.scale)]
        logits = {o: self.intercept[o] + sum(w * v for w, v in zip(self.coef[o], x)) for o in ("best", "E")}
        logits["other"] = 0.0
        top = max(logits.values())
        ex = {o: math.exp(v - top) for o, v in logits.items()}
        z = sum(ex.values())
        return {o: ex[o] / z for o in OUTCOMES}

    def to_json(self) -> dict[str, Any]:
        return {"features": self.features, "mean": self.mean, "scale": self.scale, "coef": self.coef,
                "intercept": self.intercept, "threshold": self.threshold, "fitted_on": self.fitted_on}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> Calibration:
        return cls(list(data["features"]), [float(x) for x in data["mean"]], [float(x) for x in data["scale"]],
                   {o: [float(x) for x in data["coef"][o]] for o in ("best", "E")},
                   {o: float(data["intercept"][o]) for o in ("best", "E")}, float(data["threshold"]),
                   dict(data.get("fitted_on") or {}))


def load_calibration(path: str | Path | None = None) -> Calibration | None:
    """The fitted calibration (None when the file is absent or empty: the reader's fixed rules)."""
    p = Path(path) if path else CALIBRATION_FILE
    if not p.exists():
        return None
    from memora_graph.errors import MemoraError

    try:
        data = json.loads(p.read_text(encoding="utf-8") or "null")
        return Calibration.from_json(data) if data else None
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
        raise MemoraError(f"{p}: not a calibration file ({type(exc).__name__}: {exc}); refit it with "
                          "`memora bench calibrate RUN_DIR --participants P01,P02,P03`") from exc
