"use strict";
let prompt = "wait";
let seq = -1;
let instance = "";  // the runner's state lifetime (a resumed session starts its seq again)
let trialId = "";  // the presentation a key answers: the runner takes a key only for the one it shows now
const box = document.getElementById("number");
function show(state) {
  // Answers can arrive out of order (a key's answer written late by a busy server after a newer poll's): an
  // older state must never replace a newer one, or the page would show an answered trial and send the next
  // key with that trial's id, which the runner refuses.
  const inst = state.instance || "";
  if (inst === instance && state.seq <= seq) return;
  instance = inst;
  seq = state.seq;
  prompt = state.prompt;
  const fresh = (state.trial_id || "") !== trialId;
  trialId = state.trial_id || "";
  // magnitude estimation: a free number typed into the box, sent with Enter (the box keeps what was typed
  // while the runner only adds a hint)
  box.hidden = prompt !== "number";
  if (prompt === "number" && fresh) { box.value = ""; }
  if (prompt === "number") box.focus();
  document.getElementById("message").textContent = state.message;
  document.getElementById("scale").hidden = prompt !== "rate";
  document.getElementById("hint").textContent = state.hint || "";
}
async function poll() {
  try {
    const r = await fetch("/api/subject", {cache: "no-store"});
    if (r.ok) show(await r.json());
  } catch (e) { /* runner gone: keep the last message */ }
  setTimeout(poll, 150);
}
// Keys go to the runner one at a time, in the order pressed: concurrent requests may arrive out of
// order, and the first rating key pressed (not the first to arrive) must be the one recorded.
let sending = Promise.resolve();
// A key whose request failed on the way (a connection closed under it, a server briefly full) is sent again,
// a few times: the runner takes a key once per presentation, so a repeat of one that did arrive is refused.
async function sendKey(key, trial_id) {
  for (let attempt = 0; attempt < 4; attempt++) {
    try {
      const r = await fetch("/api/key", {method: "POST", headers: {"Content-Type": "application/json"},
                                          body: JSON.stringify({key, trial_id})});
      if (r.ok) show(await r.json());
      if (r.status !== 408 && r.status !== 503) return;
    } catch (e) { /* the connection failed: try again */ }
    await new Promise((done) => setTimeout(done, 100 * (attempt + 1)));
  }
}
document.addEventListener("keydown", (ev) => {
  if (prompt === "number") {
    if (ev.key === "Enter" && !ev.repeat) {
      ev.preventDefault();
      const id = trialId, typed = box.value.trim();
      sending = sending.then(() => sendKey(typed, id));
    }
    return;  // the box takes the other keys
  }
  if (ev.repeat || ev.ctrlKey || ev.altKey || ev.metaKey) return;
  if (["Shift", "Control", "Alt", "Meta", "CapsLock", "Tab"].includes(ev.key)) return;
  ev.preventDefault();
  const key = ev.key.length === 1 ? ev.key.toLowerCase() : ev.key;
  const id = trialId;  // the presentation on screen when the key was pressed
  sending = sending.then(() => sendKey(key, id));
});
poll();
