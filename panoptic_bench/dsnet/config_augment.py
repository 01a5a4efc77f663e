"""The ``augment`` section of the DS-Net configuration (split from :mod:`.config`).

Re-exported by :mod:`panoptic_bench.dsnet.config`; import it from there.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class AugmentConfig:
    """Training augmentation (Cylinder3D / DS-Net defaults).

    ``max_points`` > 0 keeps a random subset of at most that many points of each training scan
    (a CPU speed-up; 0 keeps every point, as the paper); see ``inference.match_training_density``
    and :mod:`panoptic_bench.dsnet.data.density` for the shared policy.

    Remission (off by default): ``remission_gamma`` and ``remission_gain`` ranges (per scan,
    ``r' = clip(gain * r ** gamma, 0, 1)``) and ``remission_zero_prob`` (per point, set to 0);
    ``remission_class_gain``: a log-uniform range of one extra gain per semantic class and scan,
    applied first (:func:`panoptic_bench.dsnet.data.augment.class_remission_gain`), to the classes
    named in ``remission_class_gain_classes`` (names of the dataset's class map; empty: every class).
    Pose (off by default): ``pitch_std_deg`` / ``roll_std_deg`` of a random sensor tilt.
    Scene mixing (off by default, :mod:`panoptic_bench.dsnet.data.mix`): with probability
    ``mix_prob`` a training scan is mixed with another training scan (of another sequence where
    there is one): an azimuth sector U[``mix_sector_deg``] wide is swapped, then
    ``mix_paste_copies`` rotated copies of the partner's thing instances are pasted.
    Instance pasting (off by default, :mod:`panoptic_bench.dsnet.data.bank`): with probability
    ``paste_prob`` a training scan gets U{``paste_count``} instances of the classes named in
    ``paste_classes`` (class-balanced, rotated about the sensor axis, placed on ground with free
    space above), taken from the labelled root ``paste_bank`` (SemanticKITTI format, every
    sequence; empty: the training scans themselves), instances of ``paste_min_points`` or more.
    """

    rotate: bool = True
    flip: bool = True
    scale_range: tuple[float, float] = (0.95, 1.05)
    translate_std: tuple[float, float, float] = (0.1, 0.1, 0.1)
    max_points: int = 0
    remission_gain: tuple[float, float] = (1.0, 1.0)
    remission_gamma: tuple[float, float] = (1.0, 1.0)
    remission_zero_prob: float = 0.0
    remission_class_gain: tuple[float, float] = (1.0, 1.0)
    remission_class_gain_classes: tuple[str, ...] = ()
    pitch_std_deg: float = 0.0
    roll_std_deg: float = 0.0
    mix_prob: float = 0.0
    mix_sector_deg: tuple[float, float] = (90.0, 180.0)
    mix_paste_copies: int = 0
    paste_prob: float = 0.0
    paste_count: tuple[int, int] = (1, 4)
    paste_classes: tuple[str, ...] = ()
    paste_bank: str = ""
    paste_min_points: int = 20

    def validate(self) -> list[str]:
        lo, hi = self.scale_range
        problems = (
            [] if 0 < lo <= hi else [f"augment.scale_range must be 0 < lo <= hi, got {[lo, hi]}"]
        )
        if self.max_points < 0:
            problems.append("augment.max_points must be >= 0 (0 = keep every point)")
        for name in ("remission_gain", "remission_gamma", "remission_class_gain"):
            lo, hi = getattr(self, name)
            if not 0 < lo <= hi:
                problems.append(f"augment.{name} must be 0 < lo <= hi, got {[lo, hi]}")
        if not 0.0 <= self.remission_zero_prob < 1.0:
            problems.append("augment.remission_zero_prob must be in [0, 1)")
        if self.pitch_std_deg < 0 or self.roll_std_deg < 0 or min(self.translate_std) < 0:
            problems.append("augment.pitch_std_deg, roll_std_deg, translate_std must be >= 0")
        if not 0.0 <= self.mix_prob <= 1.0:
            problems.append("augment.mix_prob must be in [0, 1]")
        lo, hi = self.mix_sector_deg
        if not 0.0 <= lo <= hi <= 360.0:
            problems.append(f"augment.mix_sector_deg must be 0 <= lo <= hi <= 360, got {[lo, hi]}")
        if not 0 <= self.mix_paste_copies <= 16:
            problems.append("augment.mix_paste_copies must be in 0..16")
        if not 0.0 <= self.paste_prob <= 1.0:
            problems.append("augment.paste_prob must be in [0, 1]")
        lo, hi = self.paste_count
        if not 0 <= lo <= hi <= 32:
            problems.append(f"augment.paste_count must be 0 <= lo <= hi <= 32, got {[lo, hi]}")
        if self.paste_prob > 0 and not self.paste_classes:
            problems.append(
                "augment.paste_classes must name at least one class when paste_prob > 0"
            )
        if self.paste_min_points < 1:
            problems.append("augment.paste_min_points must be >= 1")
        return problems
