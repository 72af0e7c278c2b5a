"""What an audit of a run directory found (sim/experiments/soak/audit.py): each way the
run does not tell the truth, a :class:`Finding` of one of KINDS, and the counts of what
was checked."""

from __future__ import annotations

import re
from collections import Counter
from dataclasses import asdict, dataclass, field
from typing import Any

KINDS = ("traceback", "crash", "timeout", "schema", "unaccounted_robot", "pose_mismatch",
         "look_mismatch", "mirror_mismatch", "sighting_outside_image", "sighting_off_target",
         "sighting_obstructed", "correction_out_of_tolerance", "correction_misreported")


@dataclass(frozen=True)
class Finding:
    """One way a run directory does not tell the truth (``kind`` is one of KINDS)."""

    kind: str
    robot: str | None
    message: str

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class Audit:
    """Findings of one run directory and the counts of what was checked."""

    findings: list[Finding] = field(default_factory=list)
    counts: Counter[str] = field(default_factory=Counter)
    refused: Counter[str] = field(default_factory=Counter)  # placements, by reason
    refused_robots: Counter[str] = field(default_factory=Counter)  # not placed, by reason
    correction_failures: Counter[str] = field(default_factory=Counter)  # by reason
    worst: dict[str, float] = field(default_factory=dict)  # largest discrepancies seen

    def add(self, kind: str, robot: str | None, message: str) -> None:
        self.findings.append(Finding(kind, robot, message))

    def count(self, key: str, tally: str = "counts") -> None:
        """One more ``key`` in the named tally (counts, refused, refused_robots or
        correction_failures)."""
        counter: Counter[str] = getattr(self, tally)
        counter[key] += 1

    def at_most(self, name: str, value: float) -> None:
        self.worst[name] = max(self.worst.get(name, 0.0), float(value))

    def summary(self) -> dict[str, Any]:
        return {"findings": [f.as_dict() for f in self.findings], "counts": dict(self.counts),
                "refused": dict(self.refused), "refused_robots": dict(self.refused_robots),
                "correction_failures": dict(self.correction_failures), "worst": self.worst}


def reason_key(reason: str) -> str:
    """A reason with its numbers replaced by N, to count reasons alike."""
    return re.sub(r"-?\d+(\.\d+)?(e-?\d+)?", "N", reason.strip())[:160]
