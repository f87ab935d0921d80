"""What an experiment kind tells the session machinery: the interface every kind implements.

The session (:mod:`study.session.run`) sets up the device, the masking audio, the timing check and the views,
opens or resumes the subject's folder and runs the attempt loop (:mod:`study.session.loop`); it asks the
kind only what differs:

* **which kind, with what settings** -- :attr:`ExperimentKind.names` (the ``kind`` values of a protocol's
  ``[experiment]`` table it runs; the rating study, the default, has none), :meth:`configure` (its
  settings from that table, or from ``session.json`` when resumed) and :meth:`samples` (the catalog
  samples it presents);
* **what trials exist** -- :meth:`plan` (a new session's ``session.json`` entries and plan events),
  :meth:`restore` (a resumed session's rows replayed) and :meth:`next_attempt`;
* **what to present and how to ask** -- :meth:`run_attempt`, composed of the loop's one
  :meth:`~study.session.loop.SessionLoop.present` and one :meth:`~study.session.loop.SessionLoop.ask`;
* **what a row holds** -- :attr:`rows` (the trials.csv format, :mod:`plumbing.studyfiles`),
  :meth:`outcome` (an attempt's traces and row) and :meth:`recorded` (what follows once the row is on disk);
* **what the views and the end show** -- :attr:`texts`, :attr:`phrases`, :meth:`status`, :meth:`finish`,
  :meth:`summary`.

docs/architecture.md ("A new experiment kind") has a minimal kind.
"""

from __future__ import annotations

import importlib
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar

from plumbing.studyfiles import RowFormat

from .loop import Outcome, Placement


class ExperimentKind(ABC):
    """One kind of experiment run by the shared session machinery (module docstring).

    An instance is made by :meth:`create` for one session, once its folder is planned; the class-level
    members are used before (choosing the kind, reading its settings, picking its samples).
    """

    #: the ``kind`` values of a protocol's ``[experiment]`` table this kind runs (empty: the default kind,
    #: run when a protocol has no ``[experiment]`` table)
    names: ClassVar[tuple] = ()
    #: trials.csv's format
    rows: ClassVar[RowFormat]
    #: the spoken cues ``{"tap": ..., "rate": ...}`` (None: the masking audio's own, "Tap now." and
    #: "Stop. Please rate.")
    phrases: ClassVar[dict | None] = None
    #: whether the session has a familiarization phase (the protocol's ``familiarization_sample``)
    familiarization: ClassVar[bool] = True
    #: what the subject's page says; at least ``prepare``, ``paused``, ``no_tap`` and ``done``
    texts: ClassVar[dict]

    # -- before the session: the settings and the samples ------------------------------------------------------

    @classmethod
    def load(cls) -> type:
        """The kind's class itself (as :meth:`KindAt.load` gives the class of a kind named by its module)."""
        return cls

    @classmethod
    def configure(cls, table: dict | None, where: str):
        """The kind's settings from a protocol's ``[experiment]`` table (None for the default kind), or from
        ``session.json["experiment"]["config"]`` when resumed; a bad key or value is one ``ValueError``
        naming ``where`` and the key."""
        return None

    @classmethod
    @abstractmethod
    def samples(cls, config, catalog: list, choose, where: str) -> list:
        """The catalog samples the session presents (:class:`stimuli.CatalogSample`).

        Parameters
        ----------
        config
            What :meth:`configure` returned.
        catalog : list
            The whole catalog, checked.
        choose : callable
            ``choose(catalog) -> list``: the samples ``--samples`` picks (the default kind's choice; a kind
            that derives its own refuses ``--samples`` before the session starts).
        where : str
            The settings' source, for messages.
        """

    def __init__(self, plan, apparatus) -> None:
        """The kind for one session.

        Parameters
        ----------
        plan : study.session.setup.SessionPlan
            What the session settled: subject, seed, protocol, catalog, the kind's settings (``plan.config``)
            and the device's description (``plan.device_info``).
        apparatus : study.session.apparatus.Apparatus or study.session.isolated.IsolatedApparatus
            Where new stimuli get their servo loops (``add_sample``) and the reference taps are recorded.
        """
        self.session_plan = plan
        self.apparatus = apparatus
        self.protocol = plan.protocol
        #: attempts of one trial before it is recorded as not renderable (the protocol's ``max_attempts``); None
        #: for a session begun by a version without the cap (its session.json's protocol has no such key), so
        #: that its resumption replays its rows as they were run
        self.max_attempts = getattr(plan.protocol, "max_attempts", None)
        previous = getattr(plan, "previous", None)
        if previous is not None and "max_attempts" not in (previous.get("protocol") or {}):
            self.max_attempts = None
        #: catalog name -> "real" | "virtual" of every sample the session presents (a kind adds the ones it derives)
        self.sample_kinds = {s.name: s.kind for s in plan.catalog}
        #: what the operator puts on the stand (the loop asks it; a resumed session restores it)
        self.placement = Placement()

    # -- what trials exist ---------------------------------------------------------------------------------------

    @abstractmethod
    def plan(self) -> tuple[dict, list]:
        """A new session's ``session.json`` entries (besides the shared ones) and ``schedule.jsonl``'s plan
        events, written with the folder in one atomic step."""

    @abstractmethod
    def restore(self, store, rows: list, events: list) -> str | None:
        """Continue after the ``rows`` on disk (``--resume``; ``events``: schedule.jsonl's); a line the kill
        lost is written again through ``store``. Returns the note printed, or None.

        Called before anything of the resumption is written (session.json's ``resumed_at``, the ``resume``
        event): check here everything a row and the kind's own files must agree on, so that a refused session
        is left exactly as it was. ``rows`` were parsed by :attr:`rows` (``RowFormat.parse``: each value's type,
        range and the row's own consistency); what only the kind knows is its to check: each row against the
        plan or the adaptive method's replay (intensities, samples, the target), the attempt numbers against
        the logged invalid attempts, the kind's entries in ``store.session``, and its JSON-lines files
        (``store.read_json_lines``: a torn last line is kept aside; a duplicated or foreign line refused).

        Raises
        ------
        ValueError
            A row this session would not have recorded (another seed, an edited file), naming file and line.
        """

    @abstractmethod
    def next_attempt(self):
        """``(trial, attempt number)`` of the next attempt, or None when the session is done."""

    # -- what to present, how to ask, what a row holds -------------------------------------------------------

    @abstractmethod
    def run_attempt(self, loop, trial, attempt: int):
        """Present and ask (``loop``: :class:`study.session.loop.SessionLoop`); returns what :meth:`outcome`
        and :meth:`recorded` take."""

    @abstractmethod
    def outcome(self, trial, attempt: int, result, subject: str) -> Outcome:
        """The attempt's traces and row (None: not a row, e.g. an invalid forced-choice attempt)."""

    @abstractmethod
    def recorded(self, trial, attempt: int, result, row: dict | None) -> list:
        """Once the attempt's row (if any) is on disk: update the kind's state and return what to log next
        (:class:`Event` and :class:`JsonLine` items, in order)."""

    # -- the views and the end -----------------------------------------------------------------------------------

    @abstractmethod
    def status(self, result=None, row: dict | None = None) -> dict:
        """The operator page's fields now; after an attempt (``result``, ``row``) also its last attempt."""

    @abstractmethod
    def done_status(self) -> dict:
        """The operator page's fields once the session is done."""

    def reference(self, apparatus) -> dict | None:
        """The simulated participant's reference taps, recorded before the first trial, as the event logged
        (None: the kind needs none)."""
        return None

    def progress(self) -> tuple[int, int, str] | None:
        """``(attempts done, attempts planned, phase)`` for the progress line, or None for none."""
        return None

    def finish(self, session: dict) -> None:
        """Add the finished session's own entries to ``session.json`` (before ``finished_at``)."""

    @abstractmethod
    def summary(self, rows: list, store, say) -> None:
        """Print the finished session's summary (``rows``: trials.csv's)."""


@dataclass(frozen=True)
class KindAt:
    """An experiment kind named by its ``names`` and where its class is, imported only when a session is of it.

    A session's process then imports its own kind's code only: the forced-choice, adjustment and magnitude kinds
    need :mod:`psychophysics` and ``scipy.special`` (0.15-0.2 s of CPU to import), which a rating session
    never uses. ``python -m study run`` lists its kinds so (``study.cli_run.KINDS``); the session machinery
    takes these and kind classes alike (both have ``names`` and ``load()``).

    Attributes
    ----------
    names : tuple of str
        The kind's :attr:`ExperimentKind.names` (checked against the class when it is loaded).
    module : str
        Dotted name of the module defining the class, e.g. ``"study.forcedchoice.kind"``.
    attribute : str
        The class's name in that module.
    """

    names: tuple
    module: str
    attribute: str

    def load(self) -> type:
        """Import the module and return the kind's class."""
        kind = getattr(importlib.import_module(self.module), self.attribute)
        if tuple(kind.names) != tuple(self.names):  # a kind renamed in its module but not where it is listed
            raise RuntimeError(f"{self.module}.{self.attribute} runs {tuple(kind.names)}, listed as {self.names}")
        return kind
