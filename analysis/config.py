"""Analysis choices fixed before looking at the data (light module: no numpy/scipy imports)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from plumbing.validation import require_choice, require_number

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
        Fit the mixed and ordinal models of every attempt (skipped above
        ``analysis.models.MODELS_MAX_SUBJECTS`` subjects with a note).
    """

    reference: str = DEFAULT_REFERENCE
    margin: float = DEFAULT_MARGIN
    group: str = "both"
    alpha: float = 0.05
    models: bool = True

    def __post_init__(self):
        require_choice("--group", self.group, GROUPS)
        require_number("--margin", self.margin, minimum=0.0, strict=True)   # rating points
        require_number("--alpha", self.alpha, minimum=0.0, strict=True, maximum=1.0, strict_maximum=True)


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
