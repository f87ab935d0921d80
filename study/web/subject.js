"use strict";
let prompt = "wait";
let seq = -1;
function show(state) {
  if (state.seq === seq) return;
  seq = state.seq;
  prompt = state.prompt;
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
document.addEventListener("keydown", async (ev) => {
  if (ev.repeat || ev.ctrlKey || ev.altKey || ev.metaKey) return;
  if (["Shift", "Control", "Alt", "Meta", "CapsLock", "Tab"].includes(ev.key)) return;
  ev.preventDefault();
  const key = ev.key.length === 1 ? ev.key.toLowerCase() : ev.key;
  const r = await fetch("/api/key", {method: "POST", headers: {"Content-Type": "application/json"},
                                      body: JSON.stringify({key})});
  if (r.ok) show(await r.json());
});
poll();
