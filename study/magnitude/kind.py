"""Magnitude estimation as an experiment kind (:mod:`study.magnitude.experiment` for the table and plan).

One attempt of a trial: with a modulus due, the standard is presented ("This one is 10: tap now."); then the
stimulus ("Tap now."); then the subject types a number on the subject page (prompt ``number``: any number > 0,
Enter to send, ``x`` to reject). An attempt with a presentation without a tap, saturated or overpowered, or
rejected, is logged as ``invalid_attempt`` and the trial runs again; a valid one is the trial's row.

The simulated participant (sim): the stimulus's percept from the device's own taps with Weber noise
(:func:`study.varied.perceive`), and the number ``k * percept^exponent`` times log-normal response noise
(``stevens_exponent``, ``magnitude_noise_frac``), rounded to two significant digits as people round. With a
modulus, ``k`` makes the standard's remembered percept (its value with the same Weber noise, drawn when it was
last presented) give the modulus number; without one, ``k`` is the participant's own: the geometric mean
level gets a number drawn log-uniformly from 5 to 50.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

from plumbing.studyfiles import MAGNITUDE
from stimuli import load_catalog

from ..design.blocks import block_order
from ..forcedchoice.kind import operator_view
from ..session.kind import ExperimentKind
from ..session.loop import Event, Outcome
from ..session.store import utc_now
from ..varied import check_varied, percept_sigma, perceive, unit_of, varied_sample
from .experiment import KIND, MagnitudeConfig, config_from_dict, plan_trials

TEXT = {
    "prepare": "Please wait while the next sample is prepared.",
    "modulus": "This one is {number:g}: tap now.",
    "tap": "Tap now.",
    "number": "How strong was it? Type a number and press Enter (x and Enter rejects the trial).",
    "number_modulus": "How strong was it, if the first one was {number:g}? Type a number and press Enter "
                      "(x and Enter rejects the trial).",
    "done": "The study is complete. Thank you!",
    "paused": "Short pause. Please wait.",
    "no_tap": "No tap was detected. This trial will be repeated.",
}
PHRASES = {"tap": "Tap now.", "rate": "Your number?"}
#: the simulated participant's words in its seeds
PERCEPT_STREAM, NUMBER_STREAM, MODULUS_STREAM, SCALE_STREAM = 5200, 5201, 5202, 5203


@dataclass
class Attempt:
    """One attempt: its presentations ``(role, Presented)``, the answer, the percept, why it does not count."""

    trial: object
    presentations: list = field(default_factory=list)
    number: float = math.nan
    response: str = ""
    percept: float = math.nan
    reason: str = ""
    started_at: str = ""
    t0: float = 0.0


class Magnitude(ExperimentKind):
    """Magnitude estimation (module docstring)."""

    names = (KIND,)
    rows = MAGNITUDE
    phrases = PHRASES
    familiarization = False
    texts = TEXT

    @classmethod
    def configure(cls, table: dict, where: str) -> MagnitudeConfig:
        """The ``[experiment]`` table (:class:`study.magnitude.experiment.MagnitudeConfig`)."""
        return config_from_dict(table, where)

    @classmethod
    def samples(cls, config: MagnitudeConfig, load, where: str) -> list:
        """Every stimulus: each condition's sample at each level (and at the modulus)."""
        return list(stimuli(load(False), config, f"{where}: [experiment]").values())

    def __init__(self, plan, apparatus) -> None:
        super().__init__(plan, apparatus)
        exp = self.exp = plan.config
        self.subject, self.seed = plan.subject, int(plan.seed)
        self.stimuli = stimuli(load_catalog(plan.catalog_file, library_dir=plan.library_dir), exp, "[experiment]")
        self.sequence, self.order = block_order(exp.conditions, exp.order, exp.design, self.subject, self.seed,
                                                "[experiment]")
        self.trials = plan_trials(exp, self.order, self.seed, self.subject)
        info = plan.device_info
        self.force_per_amp_N_A = float(info["gear_ratio"] * info["torque_constant_Nm_A"] / info["handle_length_m"])
        self.done, self.next_number, self.invalid = 0, 1, []

    # -- what trials exist -------------------------------------------------------------------------------------
    def plan(self) -> tuple[dict, list]:
        """``session.json["experiment"]`` (the block order settled) and the plan event (every trial)."""
        exp = self.exp
        entry = {"kind": KIND, "vary": exp.vary, "unit": unit_of(exp.vary), "conditions": exp.conditions,
                 "levels": list(exp.levels), "modulus": exp.modulus,
                 "modulus_number": exp.modulus_number if exp.modulus is not None else None,
                 "order": list(self.order), "sequence": self.sequence, "design_file": exp.design or None,
                 "config": {**exp.to_dict(), "order": list(self.order), "design": ""}}
        trials = [{"trial": t.trial, "block": t.block, "condition": t.condition, "level": t.level,
                   "modulus_shown": t.modulus_shown} for t in self.trials]
        return {"experiment": entry}, [{"event": "plan", "phase": "trials", "order": list(self.order),
                                        "trials": trials}]

    def restore(self, store, rows: list, events: list) -> str:
        """Continue after the rows on disk (each must be the planned trial)."""
        for i, row in enumerate(rows):
            if i >= len(self.trials):
                raise ValueError(f"{store.trials_path} line {i + 2}: the plan has only {len(self.trials)} trials")
            t = self.trials[i]
            got = (row["condition"], row["block"], row["level"], row["modulus_shown"])
            want = (t.condition, t.block, t.level, t.modulus_shown)
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
    def _present(self, loop, a: Attempt, role: str, value: float, attempt: int, text: str) -> bool:
        pt = a.trial
        hand = None
        if self.apparatus.simulated_hand:
            k = 2 * (attempt - 1) + len(a.presentations) + 1
            hand = self.apparatus.sim_participant.plan("testing", pt.trial, k, self.protocol.tap_window_s)
        name = self.stimuli[(pt.condition, value)].name
        iv = loop.present(name, self.protocol.tap_window_s, hand=hand, text=text, home_after="tapped",
                          status=lambda: {"trial": pt.trial, "attempt": attempt, **self._status(role=role)})
        a.presentations.append((role, iv))
        if iv.n_taps == 0:
            a.reason = "no_tap"
            loop.say(TEXT["no_tap"])
        elif iv.tap.saturated:
            a.reason = "saturated"
        elif iv.contacts:
            a.reason = "overpowered"
        return not a.reason

    def run_attempt(self, loop, trial, attempt: int) -> Attempt:
        """The standard when due, the stimulus, the number."""
        exp, a = self.exp, Attempt(trial, started_at=utc_now(), t0=time.monotonic())
        if trial.modulus_shown and not self._present(loop, a, "modulus", exp.modulus, attempt,
                                                     TEXT["modulus"].format(number=exp.modulus_number)):
            return a
        if not self._present(loop, a, "stimulus", trial.level, attempt, TEXT["tap"]):
            return a
        question = TEXT["number"] if exp.modulus is None else TEXT["number_modulus"].format(number=exp.modulus_number)
        answer, contacts = loop.ask(question, "number", simulated=lambda: self.simulated_number(a, attempt))
        a.response = answer
        if contacts:
            a.reason = "overpowered"
        elif answer == "x":
            a.reason = "rejected"
        else:
            a.number = float(answer)
        return a

    def simulated_number(self, a: Attempt, attempt: int) -> str:
        """The simulated participant's number (module docstring), as the subject page would send it."""
        sim, exp = self.apparatus.sim_participant, self.exp
        cfg, pt = sim.config, a.trial
        if sim.plan("testing", pt.trial, 2 * (attempt - 1) + 1, self.protocol.tap_window_s).reject:
            return "x"
        _, iv = a.presentations[-1]
        _, a.percept = perceive(exp.vary, iv.tap.trace, self.force_per_amp_N_A, cfg,
                                sim.rng("testing", pt.trial, attempt, PERCEPT_STREAM))
        if not math.isfinite(a.percept):
            a.percept = trial_value = pt.level     # nothing to judge: the participant guesses from the level
        beta = cfg.stevens_exponent
        if exp.modulus is not None:
            # the standard as remembered: its value with Weber noise drawn when it was last presented
            last = max(t.trial for t in self.trials if t.block == pt.block and t.modulus_shown and t.trial <= pt.trial)
            e = float(sim.rng("testing", last, 0, MODULUS_STREAM).standard_normal())
            remembered = exp.modulus * math.exp(percept_sigma(exp.vary, cfg) * e)
            k = exp.modulus_number / remembered ** beta
        else:
            gm = math.exp(sum(math.log(x) for x in exp.levels) / len(exp.levels))
            u = float(sim.rng("testing", 0, 0, SCALE_STREAM).uniform(math.log(5.0), math.log(50.0)))
            k = math.exp(u) / gm ** beta
        noise = math.exp(cfg.magnitude_noise_frac * float(sim.rng("testing", pt.trial, attempt,
                                                                  NUMBER_STREAM).standard_normal()))
        number = k * a.percept ** beta * noise
        return repr(float(f"{number:.2g}")) if number > 0 else "x"

    # -- what a row holds --------------------------------------------------------------------------------------
    def outcome(self, trial, attempt: int, result: Attempt, subject: str) -> Outcome:
        """Each presentation's trace; the trial's row when the attempt counts."""
        traces = [(role, trial.trial, attempt, iv.tap.trace) for role, iv in result.presentations]
        if result.reason:
            return Outcome(traces=traces)
        exp = self.exp
        _, iv = result.presentations[-1]
        mean = (lambda xs: sum(xs) / len(xs) if xs else math.nan)
        row = {"subject": subject, "trial": trial.trial, "attempt": attempt, "block": trial.block,
               "condition": trial.condition, "sequence": self.sequence or "", "sample": iv.sample, "vary": exp.vary,
               "level": trial.level, "modulus": exp.modulus, "modulus_number":
               exp.modulus_number if exp.modulus is not None else None, "modulus_shown": trial.modulus_shown,
               "number": result.number, "n_taps": iv.n_taps, "incoming_velocity_mean_m_s": mean(iv.tap.velocities),
               "penetration_mean_m": mean(iv.tap.penetrations), "sim_percept": result.percept,
               "started_at": result.started_at, "duration_s": time.monotonic() - result.t0}
        return Outcome(traces=traces, row=row)

    def recorded(self, trial, attempt: int, result: Attempt, row: dict | None) -> list:
        """An invalid attempt is logged and the trial runs again; a valid one moves to the next trial."""
        if row is None:
            event = {"event": "invalid_attempt", "trial": trial.trial, "attempt": attempt, "reason": result.reason,
                     "response": result.response}
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
        """The operator page after an attempt."""
        shown = [iv for _, iv in result.presentations]
        return {"last_attempt": operator_view(shown, result.response, result.reason), **self._status()}

    def done_status(self) -> dict:
        """The operator page at the end."""
        return {"awaiting_confirm": False, **self._status(), "phase": "done", "place": "",
                "message": "session complete"}

    def progress(self):
        """Trials recorded of those planned."""
        return self.done, len(self.trials), KIND

    def summary(self, rows: list, store, say) -> None:
        """Per condition: the slope of log number on log level (a first look; ``analysis magnitude`` fits it)."""
        print(f"session {store.subject} complete (magnitude estimation, {self.exp.vary}): {store.dir}")
        for cond in self.order:
            pts = [(math.log(r["level"]), math.log(r["number"])) for r in rows if r["condition"] == cond]
            if len(pts) > 2:
                mx, my = (sum(p[i] for p in pts) / len(pts) for i in (0, 1))
                sxx = sum((x - mx) ** 2 for x, _ in pts)
                slope = sum((x - mx) * (y - my) for x, y in pts) / sxx if sxx > 0 else math.nan
                say(f"  {cond:24s} {len(pts)} numbers, log-log slope {slope:.3f}")


def stimuli(catalog, exp: MagnitudeConfig, where: str) -> dict:
    """``(condition, value) -> sample``: each condition's sample at each level and at the modulus."""
    by_name = {s.name: s for s in catalog}
    out = {}
    for name in exp.samples:
        if name not in by_name:
            raise ValueError(f"{where} samples: {name!r} is not in the catalog ({sorted(by_name)})")
        base = by_name[name]
        check_varied(base, exp.vary, f"{where} samples")
        for value in sorted(set(exp.levels) | ({exp.modulus} if exp.modulus is not None else set())):
            out[(name, value)] = varied_sample(base, exp.vary, value)
    return out
