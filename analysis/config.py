"""Analysis choices fixed before looking at the data (light module: no numpy/scipy imports)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

DEFAULT_REFERENCE = "wood_on_foam"
DEFAULT_MARGIN = 0.5
GROUPS = ("both", "all", "experienced")


@dataclass(frozen=True)
class AnalysisConfig:
    """Choices fixed before looking at the data.

    Attributes
    ----------
    reference : str
        Sample the equivalence tests compare against (default ``wood_on_foam``, section 4.5.5).
    margin : float
        Equivalence margin in rating points (±), > 0.
    group : str
        ``both`` | ``all`` | ``experienced``: subject groups the tests are run for.
    alpha : float
        Significance level of the summary and of ``equivalent``.
    models : bool
        Fit the mixed and ordinal models of every attempt (issue 35; skipped above
        ``analysis.models.MODELS_MAX_SUBJECTS`` subjects with a note).
    """

    reference: str = DEFAULT_REFERENCE
    margin: float = DEFAULT_MARGIN
    group: str = "both"
    alpha: float = 0.05
    models: bool = True

    def __post_init__(self):
        if self.group not in GROUPS:
            raise ValueError(f"--group must be all, experienced or both, not {self.group!r}")
        if not (self.margin > 0):
            raise ValueError(f"--margin must be > 0 rating points, got {self.margin}")
        if not (0 < self.alpha < 1):
            raise ValueError(f"--alpha must be in (0, 1), got {self.alpha}")


def check_data_folder(data_dir) -> Path:
    """``data_dir`` as a Path if it is an existing folder (of subject folders, or one subject's).

    Raises
    ------
    FileNotFoundError
        It does not exist.
    ValueError
        It is not a folder.
    """
    data_dir = Path(data_dir)
    if not data_dir.exists():
        raise FileNotFoundError(f"data folder {data_dir} does not exist")
    if not data_dir.is_dir():
        raise ValueError(f"{data_dir} is not a folder of subject folders")
    return data_dir
