"""When a placed camera's view of the insertion site has fallen enough to place it again
during the task (:class:`ReplacementTrigger`), and when a new pose is worth the move
(:func:`worth_the_move`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

# A placed camera does not move during the task, so its distance to the site and angle
# to it (DOF, Res, TAV) stay as they were: its site rating changes only by TFV (and the
# 1 - P of its own voxel). TFV is the angular clearance around the sight line / pi;
# the default run's placed cameras had TFV 0.07 and 0.23 (12 and 42 deg of clearance).
# Halving it means the nearest occlusion has come twice as close, to a few degrees,
# which the cameras' pose errors (about 1 deg, 1-2 cm) and the panel's believed pose
# (up to the 3 cm carry error) use up: the view is about to be lost.
DROP = 0.5
# Re-armed only once back above this fraction of the reference: a band of 0.3 of the
# reference between firing and re-arming, wider than the step-to-step jitter of the
# rating (the panel's believed pose moves by its step, up to 3 cm, and its voxels in
# the 5 cm map jump a voxel at a time), so a rating wavering around DROP fires once.
RECOVER = 0.8
# Steps running below DROP before firing: the task's own patience with a camera that
# loses the panel (TaskConfig.lost_limit, 3). One step's dip (a failed fit leaving the
# believed pose a step off, a voxel flip) does not fire; the panel moves at most 3 cm
# (max_step_m) a step, so a dip lasting 3 steps is the panel staying in the way.
HOLD = 3
# The gain a new pose must promise over staying. Cost of a move: in the default
# scenario a placement's move took 5.0 to 5.4 s of simulated time (the task's steps
# are 1 s apart; its task took 26 steps), during which this camera measures nothing,
# and a correction after it (16 s of computing each). Over the ~20 steps left, moving
# pays only if new x (20 - 5) > current x 20, i.e. new > 1.33 x current; the ratings
# are themselves uncertain by about 10-15 % (candidates on 5 cm voxels change Res by
# 3-6 % at 0.8-1.5 m; TFV is sampled on directions 1.6 deg apart, 0.01 of TFV). Hence
# a required gain of 0.33 and some: 50 %.
MOVE_GAIN = 0.5


def required_rating(current: float, reference: float, gain: float = MOVE_GAIN,
                    recover: float = RECOVER) -> float:
    """The site rating a new pose must promise to be worth the move: ``1 + gain`` times
    the current one (the move's cost, see MOVE_GAIN), and at least what counts as
    recovered (``recover`` x the camera's reference: moving to a pose that would itself
    count as having lost the site buys nothing)."""
    return max((1.0 + gain) * current, recover * reference)


def worth_the_move(current: float, candidate: float, reference: float,
                   gain: float = MOVE_GAIN, recover: float = RECOVER) -> bool:
    """Whether a candidate pose rated ``candidate`` for the site is worth moving a
    camera rated ``current`` there (``reference``: the camera's reference rating)."""
    return candidate > 0.0 and candidate >= required_rating(current, reference, gain, recover)


@dataclass(frozen=True)
class ReplacementTrigger:
    """When a camera's view of the site has fallen enough to place it again: below
    ``drop`` x its reference rating for ``hold`` steps running; then not again until
    its rating is back above ``recover`` x the reference (or it gets a new reference).

    The reference is the camera's site rating when it was placed, as :meth:`start`
    gives it, or else the first rating it is asked about (the task's first step).
    A camera with reference 0 never saw the site; this rule never fires for it."""

    drop: float = DROP
    recover: float = RECOVER
    hold: int = HOLD
    _reference: dict[str, float] = field(default_factory=dict, repr=False)
    _below: dict[str, int] = field(default_factory=dict, repr=False)  # steps running
    _fired: set[str] = field(default_factory=set, repr=False)  # until recovered

    def __post_init__(self) -> None:
        if not (0.0 < self.drop < self.recover <= 1.0 and self.hold >= 1):
            raise ValueError(f"need 0 < drop < recover <= 1 and hold >= 1, got drop "
                             f"{self.drop}, recover {self.recover}, hold {self.hold}")

    def start(self, name: str, reference: float) -> None:
        """Camera ``name`` holds on to ``reference`` from now on (placed, or placed
        again): its count of steps below is cleared and it may fire again."""
        self._reference[name] = float(reference)
        self._below[name] = 0
        self._fired.discard(name)

    def reference(self, name: str) -> float | None:
        return self._reference.get(name)

    def should_replace(self, name: str, rating: float) -> str | None:
        """One step's site rating of camera ``name``; why to place it again, if now."""
        reference = self._reference.get(name)
        if reference is None:
            self.start(name, rating)
            return None
        if name in self._fired:
            if rating >= self.recover * reference:
                self._fired.discard(name)
                self._below[name] = 0
            return None
        self._below[name] = self._below[name] + 1 if rating < self.drop * reference else 0
        if self._below[name] < self.hold:
            return None
        self._fired.add(name)
        self._below[name] = 0
        return (f"site rating {rating:.3g} below {self.drop:g} x {reference:.3g} (its "
                f"reference) for {self.hold} steps running")

    def worth_the_move(self, name: str, current: float, candidate: float) -> bool:
        """:func:`worth_the_move` with camera ``name``'s reference and this ``recover``."""
        return worth_the_move(current, candidate, self._reference[name],
                              recover=self.recover)
