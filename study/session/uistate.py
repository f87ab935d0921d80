"""State shared by the study runner and its views: :class:`UiState` and the abort signal :class:`Aborted`.

The attempt loop (:mod:`study.session.loop`) and the session (:mod:`study.session.run`) use
these without the web server; :mod:`study.session.webui` serves them over HTTP.
"""

from __future__ import annotations

import json
import math
import secrets
import threading
import time

RATING_KEYS = ("1", "2", "3", "4", "5", "6", "7", "x")
KEY_HINT = "Please use the keys 1 to 7 to rate, or x to reject this trial."
CHOICE_KEYS = ("1", "2", "x")
CHOICE_HINT = "Please press 1 for the first interval or 2 for the second, or x to reject this trial."
FAM_HINT = "Keep tapping on the wood. Press Enter when you are done."
#: the method of adjustment's keys: a fine or a coarse step up or down, the reference again, the match, reject
ADJUST_KEYS = ("ArrowUp", "ArrowDown", "PageUp", "PageDown", "r", "Enter", "x")
ADJUST_HINT = ("Please use the arrow keys (Page Up / Page Down for big steps), r to feel the reference again, "
               "Enter when both feel the same, or x to reject this trial.")
NUMBER_HINT = "Please type a number greater than 0 and press Enter (or x and Enter to reject this trial)."
#: the longest number the subject page takes (magnitude estimation)
NUMBER_MAX_CHARS = 12


def number_key(key: str) -> str | None:
    """A magnitude estimate typed on the subject page as the runner records it: a finite number > 0 (a decimal
    comma is read as a point) written back with ``repr``, ``"x"`` for a rejection; None if it is neither."""
    if key == "x":
        return key
    text = key.strip().replace(",", ".")
    if not text or len(text) > NUMBER_MAX_CHARS or not all(c in "0123456789.eE+-" for c in text):
        return None
    try:
        value = float(text)
    except ValueError:
        return None
    return repr(value) if math.isfinite(value) and value > 0 else None


class Aborted(RuntimeError):
    """The operator aborted the session (data written so far is kept; resume with --resume)."""


def _new_id(trial: str | None) -> str:
    """A presentation's id: what it presents (``phase:trial:attempt``, or ``view``) and 8 random hex digits."""
    return f"{trial or 'view'}:{secrets.token_hex(4)}"


def _json_safe(obj):
    """Replace NaN/inf (e.g. the mean velocity of an attempt without taps) by None: browsers reject NaN in JSON."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    return obj


class UiState:
    """State shared between the runner thread and the HTTP handler threads."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        # ``instance`` names this state's lifetime (a resumed session is a new one, its seq from 0 again): the subject
        # page takes a state only if it is newer than the one it shows (a higher seq, or another instance)
        self.subject = {"message": "Please wait.", "prompt": "wait", "hint": "", "seq": 0,
                        "trial_id": _new_id(None), "instance": secrets.token_hex(8)}
        self.operator = {"phase": "", "trial": None, "attempt": None, "place": "", "awaiting_confirm": False,
                         "progress": {}, "last_attempt": None, "paused": False, "aborted": False,
                         "message": "", "redraws": [], "seq": 0}
        self._rating = None
        self._end_familiarization = False
        self._confirmed = False
        self._answered: str | None = None  # the trial id whose key was taken
        self.keys_ignored = 0
        self.keys_refused = 0  # keys for another presentation than the current one (stale or replayed)

    # -- runner side ---------------------------------------------------------
    def set_subject(self, message: str, prompt: str, trial: str | None = None) -> None:
        """Show ``message`` on the subject view with ``prompt`` (``rate`` clears the last rating).

        Every call starts a new presentation with a new ``trial_id`` (``trial``, e.g. ``"testing:3:1"``
        for phase, trial and attempt, plus a random part): a key counts only if it carries the id of the
        presentation it answers, and only once (:meth:`subject_key`)."""
        with self._cond:
            self.subject.update(message=message, prompt=prompt, hint="", trial_id=_new_id(trial))
            self._answered = None
            self.subject["seq"] += 1
            if prompt in ("rate", "choice", "adjust", "number"):
                self._rating = None
            self._cond.notify_all()

    def set_operator(self, **fields) -> None:
        """Update fields of the operator view (subject, phase, trial n of N, time left, status...)."""
        with self._cond:
            self.operator.update(_json_safe(fields))
            self.operator["seq"] += 1
            self._cond.notify_all()

    def request_confirm(self, place: str) -> None:
        """Ask the operator to confirm that ``place`` is on the stand."""
        with self._cond:
            self._confirmed = False
            self.operator.update(place=place, awaiting_confirm=True)
            self.operator["seq"] += 1
            self._cond.notify_all()

    def confirmed(self) -> bool:
        """True once the operator confirmed and is not paused; Aborted after an abort."""
        with self._cond:
            self._check_abort()
            return self._confirmed and not self.operator["paused"]

    def rating(self):
        """The key the subject gave ('1'..'7' or 'x'; an adjustment key; a number as ``repr(float)``), or None
        yet."""
        with self._cond:
            self._check_abort()
            return self._rating

    def familiarization_ended(self) -> bool:
        """True once the subject asked to end familiarization."""
        with self._cond:
            return self._end_familiarization

    def wait(self, predicate, timeout_s: float | None = None) -> bool:
        """Block until ``predicate()`` (called under the lock) is true; raises :class:`Aborted`."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        with self._cond:
            while True:
                self._check_abort()
                if predicate():
                    return True
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    return False
                self._cond.wait(0.1 if remaining is None else min(0.1, remaining))

    def _check_abort(self) -> None:
        if self.operator["aborted"]:
            raise Aborted("the operator aborted the session")

    # -- handler side --------------------------------------------------------
    def subject_key(self, key: str, trial_id: str) -> dict:
        """Handle a key from the subject view (a rating 1-7/x, or Enter in familiarization).

        Parameters
        ----------
        key : str
            The key pressed.
        trial_id : str
            The ``trial_id`` of the presentation the key answers (the subject view sends the one it shows).

        Returns
        -------
        dict
            The view state with ``accepted``; with ``refused`` (a reason) when the key is for another
            presentation than the current one, or for one whose key was already taken: a replayed or late
            request never becomes the current trial's rating.
        """
        with self._cond:
            if trial_id != self.subject["trial_id"]:
                self.keys_refused += 1
                return {"accepted": False, "refused": "not the current trial (a late or replayed key)",
                        **self.subject}
            if self._answered == trial_id:
                self.keys_ignored += 1
                return {"accepted": False, "refused": "this trial's key was already taken", **self.subject}
            prompt = self.subject["prompt"]
            accepted = False
            taken = number_key(key) if prompt == "number" else key if (
                (prompt == "rate" and key in RATING_KEYS) or (prompt == "choice" and key in CHOICE_KEYS)
                or (prompt == "adjust" and key in ADJUST_KEYS)) else None
            if taken is not None and self._rating is None:
                self._rating = taken
                self._answered = trial_id
                accepted = True
                self.subject.update(message="Thank you.", prompt="wait", hint="")
            elif prompt == "familiarization" and key == "Enter":
                self._end_familiarization = True
                self._answered = trial_id
                accepted = True
                self.subject.update(message="Familiarization ends after this round. Please wait.", prompt="wait",
                                    hint="")
            else:
                self.keys_ignored += 1
                self.subject["hint"] = {"rate": KEY_HINT, "choice": CHOICE_HINT, "familiarization": FAM_HINT,
                                        "adjust": ADJUST_HINT, "number": NUMBER_HINT}.get(
                    prompt, "No key is needed now; please wait.")
            self.subject["seq"] += 1
            self._cond.notify_all()
            return {"accepted": accepted, **self.subject}

    def operator_action(self, action: str) -> dict:
        """Handle an operator button (confirm, pause, resume, abort, end_familiarization); ``{"ok": ...}``."""
        with self._cond:
            if action == "confirm":
                if not self.operator["awaiting_confirm"]:
                    return {"ok": False, "error": "nothing to confirm"}
                self._confirmed = True
                self.operator["awaiting_confirm"] = False
            elif action == "pause":
                self.operator["paused"] = True
            elif action == "resume":
                self.operator["paused"] = False
            elif action == "abort":
                self.operator["aborted"] = True
            elif action == "end_familiarization":
                self._end_familiarization = True
            else:
                return {"ok": False, "error": f"unknown action {action!r}"}
            self.operator["seq"] += 1
            self._cond.notify_all()
            return {"ok": True}

    def snapshot(self, which: str) -> dict:
        """A copy of the ``subject`` or ``operator`` view state."""
        with self._cond:
            return json.loads(json.dumps(self.subject if which == "subject" else self.operator))
