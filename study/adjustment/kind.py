"""The method of adjustment as an experiment kind (:mod:`study.adjustment.experiment` for the table and plan).

One attempt of a trial, through the session's attempt loop: the reference is presented (placed, cued, tapped,
homed, :meth:`study.session.loop.SessionLoop.present`), then the comparison at its start value; the subject
answers with a key (:meth:`~study.session.loop.SessionLoop.ask`, prompt ``adjust``): a fine or coarse step up
or down (the comparison is presented again at its new value), ``r`` (the reference again, then the comparison),
``Enter`` (they feel the same: the match), ``x`` (reject). An attempt with a presentation without a tap,
saturated or overpowered, or rejected, is logged as ``invalid_attempt`` and the trial starts again (next
attempt number); a trial without a match after ``max_comparisons`` is recorded unmatched. Every presentation's
trace is kept (``reference01_t003_a01.npz``, ``comparison02_t003_a01.npz``, ...).

The simulated participant (sim): percepts from the device's own taps with Weber noise (:func:`study.varied.perceive`);
its match target is the reference's percept times ``1 + adjust_bias_frac``; it steps coarsely while the
comparison feels more than a coarse step off, finely otherwise, and accepts after ``adjust_reversals`` turns of
direction. It never asks for the reference again.
"""

from __future__ import annotations

import math
import time
from collections import OrderedDict
from dataclasses import dataclass, field

from plumbing.studyfiles import ADJUSTMENT
from stimuli import load_catalog

from ..design.blocks import block_order
from ..forcedchoice.kind import operator_view
from ..session.kind import ExperimentKind
from ..session.loop import Event, Outcome
from ..session.store import utc_now
from ..varied import check_varied, perceive, unit_of, varied_sample
from .experiment import KIND, AdjustmentConfig, config_from_dict, plan_trials

TEXT = {
    "prepare": "Please wait while the next sample is prepared.",
    "reference": "Reference: tap now.",
    "comparison": "Comparison: tap now.",
    "adjust": "Does the comparison feel the same as the reference?\n"
              "Up / Down arrow: a little more / less. Page Up / Page Down: much more / less.\n"
              "r: the reference again. Enter: they feel the same. x: reject the trial.",
    "done": "The study is complete. Thank you!",
    "paused": "Short pause. Please wait.",
    "no_tap": "No tap was detected. This trial will start again.",
}
PHRASES = {"tap": "Tap now.", "rate": "Adjust."}
#: the comparisons' servo loops kept at once (each holds its log: ~6 MB with 5 s windows)
LOOPS_KEPT = 12
#: the simulated participant's words in its seeds (:meth:`study.session.participants.SimulatedParticipant.rng`)
REFERENCE_STREAM, COMPARISON_STREAM = 5000, 5100


@dataclass
class Attempt:
    """One attempt: its presentations ``(role, index, Presented)``, the comparison values, the steps taken,
    whether it matched, why it does not count ("" when it does), the reference's percept (sim)."""

    trial: object
    presentations: list = field(default_factory=list)
    values: list = field(default_factory=list)
    n_steps: int = 0
    matched: int = 0
    reason: str = ""
    response: str = ""
    percept: float = math.nan
    started_at: str = ""
    t0: float = 0.0


class Adjustment(ExperimentKind):
    """The method of adjustment (module docstring)."""

    names = (KIND,)
    rows = ADJUSTMENT
    phrases = PHRASES
    familiarization = False
    texts = TEXT

    @classmethod
    def configure(cls, table: dict, where: str) -> AdjustmentConfig:
        """The ``[experiment]`` table (:class:`study.adjustment.experiment.AdjustmentConfig`)."""
        return config_from_dict(table, where)

    @classmethod
    def samples(cls, config: AdjustmentConfig, load, where: str) -> list:
        """The references (derived at their values, or the catalog's reference samples)."""
        refs, _ = references(load(False), config, f"{where}: [experiment]")
        return list(refs.values())

    def __init__(self, plan, apparatus) -> None:
        super().__init__(plan, apparatus)
        exp = self.exp = plan.config
        self.subject, self.seed = plan.subject, int(plan.seed)
        catalog = load_catalog(plan.catalog_file, library_dir=plan.library_dir)
        self.refs, self.ref_values = references(catalog, exp, "[experiment]")
        self.base = next(s for s in catalog if s.name == exp.sample)
        self.sequence, self.order = block_order(exp.conditions, exp.order, exp.design, self.subject, self.seed,
                                                "[experiment]")
        self.trials = plan_trials(exp, self.order, self.seed, self.subject)
        info = plan.device_info
        self.force_per_amp_N_A = float(info["gear_ratio"] * info["torque_constant_Nm_A"] / info["handle_length_m"])
        self.loaded: OrderedDict = OrderedDict()
        self.fixed = {s.name for s in plan.catalog}
        self.done, self.next_number, self.invalid = 0, 1, []

    # -- what trials exist -------------------------------------------------------------------------------------
    def plan(self) -> tuple[dict, list]:
        """``session.json["experiment"]`` (the block order settled: a resumed session reads it, not the design
        file) and the plan event (every trial)."""
        exp = self.exp
        config = {**exp.to_dict(), "order": list(self.order), "design": ""}
        entry = {"kind": KIND, "vary": exp.vary, "unit": unit_of(exp.vary), "conditions": exp.conditions,
                 "reference_values": self.ref_values, "order": list(self.order), "sequence": self.sequence,
                 "design_file": exp.design or None, "config": config}
        trials = [{"trial": t.trial, "block": t.block, "condition": t.condition, "start_value": self._start(t),
                   "side": t.side} for t in self.trials]
        return {"experiment": entry}, [{"event": "plan", "phase": "trials", "order": list(self.order),
                                        "trials": trials}]

    def _start(self, t) -> float:
        return self.exp.value(self.ref_values[t.condition], t.start_k)

    def restore(self, store, rows: list, events: list) -> str:
        """Continue after the rows on disk (each must be the planned trial); the next trial's attempt number
        follows its logged invalid attempts."""
        for i, row in enumerate(rows):
            if i >= len(self.trials):
                raise ValueError(f"{store.trials_path} line {i + 2}: the plan has only {len(self.trials)} trials")
            t = self.trials[i]
            got = (row["condition"], row["block"], row["start_value"], row["start_side"])
            want = (t.condition, t.block, self._start(t), t.side)
            if got != want:
                raise ValueError(f"{store.trials_path} line {i + 2}: trial {i + 1} is {got}, but this seed plans "
                                 f"{want}; the file does not belong to this session")
        self.done = len(rows)
        self.invalid = [e for e in events if e.get("event") == "invalid_attempt"]
        self.next_number = 1 + sum(1 for e in self.invalid if e.get("trial") == self.done + 1)
        return f"resuming {self.subject}: {len(rows)} trials on disk"

    def next_attempt(self):
        """``(planned trial, attempt)``, or None when every trial is recorded."""
        if self.done >= len(self.trials):
            return None
        return self.trials[self.done], self.next_number

    # -- one attempt -------------------------------------------------------------------------------------------
    def _comparison(self, value: float) -> str:
        """The comparison at ``value``: its servo loop made on first use, the least recently used dropped."""
        sample = varied_sample(self.base, self.exp.vary, value)
        if sample.name in self.fixed:       # a reference's own value: its loop stays for the whole session
            return sample.name
        if sample.name in self.loaded:
            self.loaded.move_to_end(sample.name)
            return sample.name
        self.apparatus.add_sample(sample)
        self.sample_kinds[sample.name] = sample.kind
        self.loaded[sample.name] = True
        while len(self.loaded) > LOOPS_KEPT:
            old, _ = self.loaded.popitem(last=False)
            self.apparatus.drop_sample(old)
        return sample.name

    def _present(self, loop, a: Attempt, role: str, name: str, attempt: int):
        """Present ``name`` as the reference or the comparison; True if the presentation counts."""
        idx = len(a.presentations) + 1
        pt = a.trial
        hand = None
        if self.apparatus.simulated_hand:
            hand = self.apparatus.sim_participant.plan("testing", pt.trial, 100 * (attempt - 1) + idx,
                                                       self.protocol.tap_window_s)
        iv = loop.present(name, self.protocol.tap_window_s, hand=hand, text=TEXT[role], home_after="tapped",
                          status=lambda: {"trial": pt.trial, "attempt": attempt, **self._status(role=role)})
        a.presentations.append((role, idx, iv))
        if iv.n_taps == 0:
            a.reason = "no_tap"
            loop.say(TEXT["no_tap"])
        elif iv.tap.saturated:
            a.reason = "saturated"
        elif iv.contacts:
            a.reason = "overpowered"
        return not a.reason

    def run_attempt(self, loop, trial, attempt: int) -> Attempt:
        """The reference, then comparisons and the subject's keys until the match (module docstring)."""
        exp, a = self.exp, Attempt(trial, started_at=utc_now(), t0=time.monotonic())
        ref_name, ref_value = self.refs[trial.condition].name, self.ref_values[trial.condition]
        if not self._present(loop, a, "reference", ref_name, attempt):
            return a
        sim = SimulatedAdjuster(self, trial, attempt, a) if loop.simulated else None
        k = trial.start_k
        while True:
            a.values.append(exp.value(ref_value, k))
            if not self._present(loop, a, "comparison", self._comparison(a.values[-1]), attempt):
                return a
            if len(a.values) >= exp.max_comparisons:
                return a
            key, contacts = loop.ask(TEXT["adjust"], "adjust", simulated=sim.key if sim else None)
            a.response = key
            if contacts:
                a.reason = "overpowered"
            elif key == "x":
                a.reason = "rejected"
            elif key == "Enter":
                a.matched = 1
            if a.reason or a.matched:
                return a
            if key == "r":
                if not self._present(loop, a, "reference", ref_name, attempt):
                    return a
                continue
            step = {"ArrowUp": 1, "ArrowDown": -1, "PageUp": exp.fine_per_coarse, "PageDown": -exp.fine_per_coarse}
            k = max(-exp.max_steps, min(exp.max_steps, k + step[key]))
            a.n_steps += 1

    # -- what a row holds --------------------------------------------------------------------------------------
    def outcome(self, trial, attempt: int, result: Attempt, subject: str) -> Outcome:
        """Every presentation's trace; the trial's row when the attempt counts."""
        traces = [(f"{role}{idx:02d}", trial.trial, attempt, iv.tap.trace) for role, idx, iv in result.presentations]
        if result.reason:
            return Outcome(traces=traces)
        exp = self.exp
        n_ref = sum(1 for role, _, _ in result.presentations if role == "reference")
        row = {"subject": subject, "trial": trial.trial, "attempt": attempt, "block": trial.block,
               "condition": trial.condition, "sequence": self.sequence or "",
               "reference_sample": self.refs[trial.condition].name, "reference_value": self.ref_values[trial.condition],
               "comparison_sample": exp.sample, "vary": exp.vary, "start_value": self._start(trial),
               "start_side": trial.side, "final_value": result.values[-1], "matched": result.matched,
               "n_steps": result.n_steps, "n_comparisons": len(result.values), "n_references": n_ref,
               "values": result.values, "sim_percept_reference": result.percept, "started_at": result.started_at,
               "duration_s": time.monotonic() - result.t0}
        return Outcome(traces=traces, row=row)

    def recorded(self, trial, attempt: int, result: Attempt, row: dict | None) -> list:
        """An invalid attempt is logged and the trial starts again; a valid one moves to the next trial."""
        if row is None:
            event = {"event": "invalid_attempt", "trial": trial.trial, "attempt": attempt, "reason": result.reason,
                     "response": result.response, "presentations": len(result.presentations)}
            self.invalid.append(event)
            self.next_number += 1
            return [Event(event)]
        self.done += 1
        self.next_number = 1
        return []

    # -- the views and the end ---------------------------------------------------------------------------------
    def _status(self, **extra) -> dict:
        total = len(self.trials)
        return {"subject": self.subject, "phase": KIND, "trials_valid": self.done, "trials_total": total,
                "trial_n": min(total, self.done + 1),
                "progress": {"trials": {"total": total, "attempts": self.done + len(self.invalid), "valid": self.done}},
                "finished": self.done >= total, **extra}

    def status(self, result: Attempt = None, row: dict | None = None) -> dict:
        """The operator page after an attempt: its presentations and the match."""
        shown = [iv for _, _, iv in result.presentations]
        return {"last_attempt": operator_view(shown, result.response, result.reason), **self._status()}

    def done_status(self) -> dict:
        """The operator page at the end."""
        return {"awaiting_confirm": False, **self._status(), "phase": "done", "place": "",
                "message": "session complete"}

    def progress(self):
        """Trials recorded of those planned."""
        return self.done, len(self.trials), KIND

    def summary(self, rows: list, store, say) -> None:
        """Per condition: the matches' geometric mean (the PSE) against the reference."""
        print(f"session {store.subject} complete (method of adjustment, {self.exp.vary}): {store.dir}")
        for cond in self.order:
            finals = [r["final_value"] for r in rows if r["condition"] == cond and r["matched"]]
            if finals:
                pse = math.exp(sum(math.log(v) for v in finals) / len(finals))
                say(f"  {cond:24s} reference {self.ref_values[cond]:.4g} {unit_of(self.exp.vary)}: "
                    f"{len(finals)} matches, PSE {pse:.4g}")


def references(catalog, exp: AdjustmentConfig, where: str) -> tuple[dict, dict]:
    """Each condition's reference sample and its value of ``vary``; the comparison's sample checked."""
    by_name = {s.name: s for s in catalog}

    def get(name: str, key: str):
        if name not in by_name:
            raise ValueError(f"{where} {key} = {name!r} is not in the catalog ({sorted(by_name)})")
        return by_name[name]

    check_varied(get(exp.sample, "sample"), exp.vary, f"{where} sample")
    refs, values = {}, {}
    if exp.references:
        base = get(exp.reference_sample or exp.sample, "reference_sample")
        check_varied(base, exp.vary, f"{where} reference_sample")
        for cond, v in zip(exp.conditions, exp.references):
            refs[cond], values[cond] = varied_sample(base, exp.vary, v), v
    else:
        for name in exp.reference_samples:
            s = get(name, "reference_samples")
            refs[name], values[name] = s, check_varied(s, exp.vary, f"{where} reference_samples")
    return refs, values


class SimulatedAdjuster:
    """The simulated participant's keys in one attempt (module docstring)."""

    def __init__(self, kind: Adjustment, trial, attempt: int, a: Attempt) -> None:
        self.kind, self.trial, self.attempt, self.a = kind, trial, attempt, a
        sim = kind.apparatus.sim_participant
        self.sim, self.cfg = sim, sim.config
        _, _, iv = a.presentations[0]
        rng = sim.rng("testing", trial.trial, attempt, REFERENCE_STREAM)
        _, a.percept = perceive(kind.exp.vary, iv.tap.trace, kind.force_per_amp_N_A, self.cfg, rng)
        self.target = a.percept * (1.0 + self.cfg.adjust_bias_frac)
        self.reject = sim.plan("testing", trial.trial, 100 * (attempt - 1) + 1, kind.protocol.tap_window_s).reject
        self.direction = 0
        self.turns = 0

    def key(self) -> str:
        """The key after the last comparison."""
        if self.reject:
            return "x"
        role, idx, iv = self.a.presentations[-1]
        rng = self.sim.rng("testing", self.trial.trial, self.attempt, COMPARISON_STREAM + idx)
        _, percept = perceive(self.kind.exp.vary, iv.tap.trace, self.kind.force_per_amp_N_A, self.cfg, rng)
        if not (math.isfinite(percept) and math.isfinite(self.target)):
            return "r" if math.isfinite(percept) else "ArrowUp"
        d = math.log(percept / self.target)
        direction = 1 if d < 0 else -1
        coarse = abs(d) > math.log1p(self.kind.exp.coarse_step)
        if self.direction and direction != self.direction and not coarse:
            self.turns += 1
        self.direction = direction
        if self.turns >= self.cfg.adjust_reversals:
            return "Enter"
        return ("PageUp" if coarse else "ArrowUp") if direction > 0 else ("PageDown" if coarse else "ArrowDown")
