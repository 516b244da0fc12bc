"""What ``handover train`` can be asked for, as one frozen dataclass, and the estimator it names.

Parameters apart from fitted state (as scikit-learn separates them): ``handover train`` turns its
arguments into :class:`TrainOptions` once (``trainer.commands.train_cli``); the demo and library users build
one directly and call ``trainer.pipeline.train``. The model's defaults come from the product
default (``trainer.defaults.DEFAULT_MODEL``); the argparse defaults come from here.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, fields

from firmware_io.errors import HandoverError
from trainer.defaults import BOW_ALONE_KERNEL, DEFAULT_MODEL
from trainer.feature_weighting import FEATURE_WEIGHTINGS
from trainer.recorded_idle import DORMANT_CUT, DORMANT_CUTS

__all__ = [
    "ASSIGNMENTS", "FEATURE_WEIGHTING_CHOICES", "KERNELS", "TRIGGERS", "OptionsError", "TrainOptions",
    "build_estimator", "parse_features", "parse_windows"
]

KERNELS = ("rbf", "linear")
ASSIGNMENTS = ("hard", "soft")
TRIGGERS = ("onset", "threshold")
EARLY = ("on", "off")
FEATURE_WEIGHTING_CHOICES = (*(w for w in FEATURE_WEIGHTINGS if w is not None), "none")


class OptionsError(HandoverError, ValueError):
    """Options that cannot train; the message names the option as the command spells it."""


@dataclass(frozen=True)
class TrainOptions:
    """Every option of ``handover train`` (the field names are the command's, ``--no-per-pad`` is
    ``per_pad=False``). ``quiet`` silences progress on stderr; ``json``: the command prints the metrics as
    JSON on stdout (and the headline on stderr unless ``quiet``)."""

    data: tuple[str, ...] | None = None
    """Folders of recordings or capture folders (``--data`` given once per folder); None: simulate."""
    out: str = "report"
    pads: str = str(DEFAULT_MODEL["pads"])
    K: int = int(DEFAULT_MODEL["K"])
    W: int = int(DEFAULT_MODEL["W"])
    T: int = int(DEFAULT_MODEL["T"])
    features: tuple[str, ...] | None = None
    """Feature families; None: bow alone when a BoW-only option is given, else the product default."""
    kernel: str | None = None
    """SVM kernel; None: linear for bow alone, else the product default's."""
    C: float | None = None
    gamma: float | None = None
    feature_weighting: str | None = None
    """A rule of ``trainer.feature_weighting`` for the standardised features, ``"none"``: unweighted;
    None: the product default's with the default families, else unweighted."""
    per_pad: bool = bool(DEFAULT_MODEL["per_pad"])
    select: bool = False
    latency_budget_us: float | None = None
    windows: tuple[int, ...] | None = None
    """Several BoW window lengths at once (replaces W)."""
    assignment: str = "hard"
    temperature: float = 1.0
    level_features: bool = False
    scale_features: bool = False
    trigger: str | None = None
    fraction: float | None = None
    seed: int = 0
    repeats: int = 5
    sweep_file: str | None = None
    no_sweep: bool = False
    dormant: bool = True
    replay: bool = True
    """Replay each held-out subject's recording through the daemon (stream figures in the report)."""
    real_idle: bool | None = None
    """Replay the real recordings without a handover (../shared/data) through the model; None: for
    models trained on real recordings, where the folder is present."""
    """Add the dormant class from the recordings' idle stretches (when they hold any)."""
    no_onnx: bool = False
    prior: bool = True
    """With recordings (``data``): add the product's prior (trainer.prior), its weight chosen by grouped
    cross-validation on the lab's subjects; False: the lab's data alone."""
    early: str = "on"
    """``on``: early heads and their report rule in the model (trainer.early); ``off``: the full window only."""
    dormant_cut: str = DORMANT_CUT
    """How the dormant windows are cut from the idle, the lab's and the prior's (trainer.recorded_idle.DORMANT_CUTS)."""
    json: bool = False
    quiet: bool = False

    def __post_init__(self) -> None:
        """Library users may write lists as the command does: ``features="stats,bow"``, ``windows="5,7"``,
        and one folder as ``data="rec"``."""
        if isinstance(self.data, str | os.PathLike):
            object.__setattr__(self, "data", (str(self.data),))
        elif self.data is not None:
            object.__setattr__(self, "data", tuple(str(d) for d in self.data) or None)
        if isinstance(self.features, str):
            object.__setattr__(self, "features", tuple(p.strip() for p in self.features.split(",") if p.strip()))
        if isinstance(self.windows, str):
            object.__setattr__(self, "windows", parse_windows(self.windows))

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))

    @property
    def bow_only(self) -> bool:
        """An option only the BoW family reads (or ``--no-per-pad``, the paper's configuration)."""
        return bool(not self.per_pad or self.windows or self.assignment != "hard" or self.level_features
                    or self.scale_features)

    @property
    def families(self) -> tuple[str, ...]:
        """``features``, else bow alone when a BoW-only option is given, else the product default."""
        if self.features:
            return tuple(self.features)
        return ("bow",) if self.bow_only else tuple(DEFAULT_MODEL["families"])

    @property
    def weighting(self) -> str | None:
        """The feature weighting the estimator gets (``feature_weighting``; see there)."""
        if self.feature_weighting is not None:
            return None if self.feature_weighting == "none" else self.feature_weighting
        uses_default = not self.features and not self.bow_only
        return DEFAULT_MODEL["feature_weighting"] if uses_default else None

    @property
    def svm_kernel(self) -> str:
        """``kernel``, else linear for bow alone (BowSVC's product setting), else the default's kernel."""
        if self.kernel:
            return self.kernel
        return BOW_ALONE_KERNEL if self.families == ("bow",) else str(DEFAULT_MODEL["kernel"])

    @property
    def window(self) -> int | tuple[int, ...]:
        """The BoW window option: ``windows`` (one length: an int, the paper's single codebook), else W."""
        if not self.windows:
            return self.W
        return self.windows[0] if len(self.windows) == 1 else tuple(self.windows)

    def estimator_options(self) -> dict:
        """The BowSVC keyword arguments of the options beyond the paper (paper's values by default)."""
        return {"window": self.window, "assignment": self.assignment, "temperature": self.temperature,
                "level_features": self.level_features, "scale_features": self.scale_features}

    def check(self) -> None:
        """Raise OptionsError (one line naming the option) for values that cannot train."""
        if self.K < 1 or self.W < 1 or self.T < 2:
            raise OptionsError(f"K, W must be >= 1 and T >= 2 (got K={self.K}, W={self.W}, T={self.T})")
        if self.features is not None:
            check_families(self.features, ",".join(self.features))
        check_pads(self.pads, simulated=not self.data)
        if self.data and len({os.path.realpath(d) for d in self.data}) != len(self.data):
            raise OptionsError(f"--data {' '.join(self.data)}: a folder given twice (its recordings would count twice)")
        uses_bow = "bow" in self.families
        if uses_bow and self.T - 1 < self.W:  # W is the BoW window: other families do not read it
            raise OptionsError(f"W={self.W} needs T >= {self.W + 1} (got T={self.T})")
        if self.repeats < 2:
            raise OptionsError("--repeats must be at least 2 (mean +/- std)")
        if self.windows is not None:
            check_windows(self.windows, ",".join(str(w) for w in self.windows))
            if uses_bow and max(self.windows) > self.T - 1:
                raise OptionsError(f"--windows {','.join(str(w) for w in self.windows)} needs T >= "
                                   f"{max(self.windows) + 1} (got T={self.T})")
        if not self.temperature > 0:
            raise OptionsError(f"--temperature must be positive (got {self.temperature})")
        if self.latency_budget_us is not None and not self.latency_budget_us > 0:
            raise OptionsError(f"--latency-budget-us must be positive (got {self.latency_budget_us})")
        if self.feature_weighting not in (None, "none") and self.families == ("bow",):
            raise OptionsError("--feature-weighting applies to the feature families, not to bow alone")
        for name, value, allowed in (("--kernel", self.kernel, KERNELS), ("--assignment", self.assignment, ASSIGNMENTS),
                                     ("--trigger", self.trigger, TRIGGERS), ("--early", self.early, EARLY),
                                     ("--dormant-cut", self.dormant_cut, DORMANT_CUTS),
                                     ("--feature-weighting", self.feature_weighting, FEATURE_WEIGHTING_CHOICES)):
            if value is not None and value not in allowed:
                raise OptionsError(f"{name} {value!r}: use one of {', '.join(allowed)}")
        if self.dormant_cut != DORMANT_CUT and not (self.data and self.dormant):
            raise OptionsError(f"--dormant-cut {self.dormant_cut}: it cuts the dormant class from recorded idle; "
                               "give --data and leave out --no-dormant")

    def command_line(self) -> str:
        """The exact command that reproduces this run (written at the top of the report)."""
        parts = ["handover", "train"]
        for folder in self.data or ():
            parts += ["--data", folder]
        parts += ["--out", str(self.out), "--pads", self.pads, "--K", str(self.K), "--W", str(self.W),
                  "--T", str(self.T), "--features", ",".join(self.families), "--kernel", self.svm_kernel,
                  "--seed", str(self.seed), "--repeats", str(self.repeats)]
        if self.trigger:
            parts += ["--trigger", self.trigger]
        if self.fraction is not None:
            parts += ["--fraction", str(self.fraction)]
        for flag, value in (("--C", self.C), ("--gamma", self.gamma),
                            ("--feature-weighting", self.weighting if self.families != ("bow",) else None),
                            ("--sweep", self.sweep_file)):
            if value is not None:
                parts += [flag, str(value)]
        if self.windows:
            parts += ["--windows", ",".join(str(w) for w in self.windows)]
        if self.assignment != "hard":
            parts += ["--assignment", self.assignment, "--temperature", str(self.temperature)]
        parts.append("--per-pad" if self.per_pad else "--no-per-pad")
        if self.early != "on":
            parts += ["--early", self.early]
        if self.dormant_cut != DORMANT_CUT:
            parts += ["--dormant-cut", self.dormant_cut]
        if self.select:
            parts.append("--select")
            if self.latency_budget_us is not None:
                parts += ["--latency-budget-us", str(self.latency_budget_us)]
        for flag, on in (("--level-features", self.level_features), ("--scale-features", self.scale_features),
                         ("--no-sweep", self.no_sweep), ("--no-onnx", self.no_onnx),
                         ("--no-dormant", not self.dormant), ("--no-replay", not self.replay),
                         ("--no-prior", not self.prior and bool(self.data)),
                         ("--real-idle", self.real_idle is True), ("--no-real-idle", self.real_idle is False)):
            if on:
                parts.append(flag)
        return " ".join(parts)


def parse_features(text: str) -> tuple[str, ...]:
    """``"stats,bow"`` -> ("stats", "bow"); OptionsError for unknown or repeated names."""
    names = tuple(p.strip() for p in text.split(",") if p.strip())
    check_families(names, text)
    return names


def check_families(names: tuple[str, ...], shown: str) -> None:
    from trainer.feature_svc import FAMILIES

    bad = [n for n in names if n not in FAMILIES]
    if not names or bad or len(set(names)) != len(names):
        raise OptionsError(f"--features {shown!r}: give distinct names from {', '.join(FAMILIES)}, e.g. stats,bow")


def check_pads(pads: str, simulated: bool) -> None:
    """A pad selection no SDH-2 could satisfy, before hours of simulating or loading. The simulated protocol
    is an SDH-2; recorded data is checked against its own layout once loaded (only the syntax here)."""
    from firmware_io.layout import LayoutError, SensorLayout

    try:
        SensorLayout.sdh2().pads(pads)
    except LayoutError as exc:
        if simulated or "no matrix" not in str(exc):
            raise OptionsError(f"--pads {pads!r}: {exc}") from None


def parse_windows(text: str) -> tuple[int, ...]:
    """``"5,7,9"`` -> (5, 7, 9); OptionsError for anything else."""
    try:
        lengths = tuple(int(p) for p in text.split(",") if p.strip())
    except ValueError:
        raise OptionsError(f"--windows {text!r}: give window lengths separated by commas, e.g. 5,7,9") from None
    check_windows(lengths, text)
    return lengths


def check_windows(lengths: tuple[int, ...], shown: str) -> None:
    if not lengths or min(lengths) < 1 or len(set(lengths)) != len(lengths):
        raise OptionsError(f"--windows {shown!r}: lengths must be distinct integers >= 1")


def build_estimator(options: TrainOptions, ds):
    """BowSVC for bow alone (every paper option), else FeatureSVC over the chosen families."""
    from trainer.defaults import paper_classifier
    from trainer.feature_svc import FeatureSVC

    o = options
    if o.families == ("bow",):
        return paper_classifier(ds.pad_sizes, o.seed, n_words=o.K, kernel=o.svm_kernel, C=o.C, gamma=o.gamma,
                                per_pad=o.per_pad, fullscale=ds.fullscale, **o.estimator_options())
    shapes = [(ds.layout.matrices[p].cells_y, ds.layout.matrices[p].cells_x) for p in ds.pads]
    return FeatureSVC(families=o.families, pad_sizes=tuple(ds.pad_sizes), pad_shapes=shapes, kernel=o.svm_kernel,
                      C=o.C, gamma=o.gamma, n_words=o.K, window=o.W, random_state=o.seed, fullscale=ds.fullscale,
                      feature_weighting=o.weighting)
