"use strict";
const token = new URLSearchParams(location.search).get("token") || "";
const H = {"X-Study-Token": token, "Content-Type": "application/json"};
function fmt(list, scale, digits) { return (list || []).map(v => (v * scale).toFixed(digits)).join(", "); }
function rows(table, pairs) {
  table.innerHTML = "";
  for (const [k, v, flag] of pairs) {
    const tr = table.insertRow();
    tr.insertCell().textContent = k;
    const td = tr.insertCell(); td.textContent = v;
    if (flag) td.className = "flag";
  }
}
function show(s) {
  const place = document.getElementById("place");
  place.textContent = s.place ? "Place: " + s.place : "-";
  place.className = s.awaiting_confirm ? "waiting" : "";
  const live = !s.aborted && !s.finished;
  const enable = {confirm: live && s.awaiting_confirm && !s.paused, pause: live && !s.paused,
                  resume: live && s.paused, endfam: live && s.phase === "familiarization", abort: live};
  for (const [id, on] of Object.entries(enable)) document.getElementById(id).disabled = !on;
  const text = (id, v) => { document.getElementById(id).textContent = (v === null || v === undefined || v === "") ? "-" : v; };
  text("subject", s.subject);
  text("phase", s.phase);
  text("trialn", s.trial_n ? `${s.trial_n} of ${s.trials_total} (${s.trials_valid} valid)` :
                 (s.trials_total ? `familiarization window ${s.trial ?? "-"}; then ${s.trials_total} trials` : null));
  text("timeleft", s.time_left_s == null ? null :
                   `${Math.floor(s.time_left_s / 60)} min ${Math.round(s.time_left_s % 60)} s`);
  text("lastrating", s.last_rating);
  text("audiolink", `${s.audio ?? "-"} / ${s.link ?? "-"}`);
  document.getElementById("status").textContent =
    `${s.phase || ""} trial ${s.trial ?? "-"} attempt ${s.attempt ?? "-"}` +
    (s.paused ? " | PAUSED" : "") + (s.aborted ? " | ABORTED" : "") + (s.message ? " | " + s.message : "");
  rows(document.getElementById("progress"),
       Object.entries(s.progress || {}).map(([k, v]) => [k, `${v.valid} / ${v.total} valid, ${v.attempts} attempts`]));
  const a = s.last_attempt;
  rows(document.getElementById("last"), a ? [
    ["sample", `${a.sample} (${a.kind})`], ["taps", a.n_taps],
    ["incoming velocities (m/s)", fmt(a.incoming_velocities_m_s, 1, 3)],
    ["penetration depths (mm)", fmt(a.penetration_depths_m, 1000, 2)],
    ["clipped / saturated", a.saturated ? "yes (repeat)" : "no", a.saturated],
    ["overpowered homing", a.overpowered ? "yes (repeat)" : "no", a.overpowered],
    ["rating", a.rejected ? "x (rejected, repeat)" : (a.rating ?? "-"), a.rejected],
  ] : []);
  table(s.table);
  const ol = document.getElementById("redraws");
  ol.innerHTML = "";
  for (const r of s.redraws || []) {
    const li = document.createElement("li");
    li.textContent = `${r.phase} trial ${r.trial} (${r.sample}) attempt ${r.attempt}: ${r.reason}`;
    ol.appendChild(li);
  }
}
const SVG = "http://www.w3.org/2000/svg";
function table(t) {
  // a 3-DOF session: the samples' blocks seen from above (mm, y up) and the hand's dot
  const box = document.getElementById("tablebox");
  if (!t || !t.hand) { box.hidden = true; return; }
  box.hidden = false;
  const svg = document.getElementById("table");
  svg.replaceChildren();
  for (const b of t.blocks || []) {
    const r = document.createElementNS(SVG, "rect");
    r.setAttribute("x", b.x0_mm); r.setAttribute("y", -b.y1_mm);
    r.setAttribute("width", b.x1_mm - b.x0_mm); r.setAttribute("height", b.y1_mm - b.y0_mm);
    r.setAttribute("class", b.name === t.presented ? "block presented" : "block");
    r.setAttribute("data-name", b.name);
    svg.appendChild(r);
  }
  const h = t.hand;
  const dot = document.createElementNS(SVG, "circle");
  dot.setAttribute("id", "handdot");
  dot.setAttribute("cx", h.x_mm); dot.setAttribute("cy", -h.y_mm); dot.setAttribute("r", 2);
  svg.appendChild(dot);
  document.getElementById("hand").textContent =
    `x ${h.x_mm.toFixed(1)} mm, y ${h.y_mm.toFixed(1)} mm: ${h.height_mm.toFixed(1)} mm above ${h.over}` +
    (t.presented ? ` (presented: ${t.presented})` : "");
}
let lastOk = null;
function runner(ok, why) {
  const el = document.getElementById("runner");
  if (ok) { lastOk = new Date(); el.className = "ok"; el.textContent = "runner running (updated " +
            lastOk.toLocaleTimeString() + ")"; return; }
  el.className = "stopped";
  el.textContent = "RUNNER STOPPED: " + why + (lastOk ? " (last answer " + lastOk.toLocaleTimeString() + ")" : "");
  for (const id of ["confirm", "pause", "resume", "endfam", "abort"]) document.getElementById(id).disabled = true;
}
function complete(s) {
  // a normal finish: the final state stays on the page, the runner then exits (no "runner stopped" alarm)
  const el = document.getElementById("runner");
  el.className = "complete";
  el.textContent = "SESSION COMPLETE: " + (s.trials_valid ?? "-") + " of " + (s.trials_total ?? "-") +
                   " trials valid; the data is saved. You can close this page.";
  document.getElementById("place").textContent = "Session complete";
  document.getElementById("place").className = "complete";
  for (const id of ["confirm", "pause", "resume", "endfam", "abort"]) document.getElementById(id).disabled = true;
}
async function poll() {
  try {
    const r = await fetch("/api/operator?token=" + encodeURIComponent(token), {cache: "no-store"});
    if (r.ok) {
      const s = await r.json();
      show(s);
      if (s.finished) { complete(s); return; }          // final: stop asking
      if (s.aborted) runner(false, "aborted"); else runner(true);
    } else runner(false, "server answered " + r.status);
  } catch (e) { runner(false, "no answer from the runner"); }
  setTimeout(poll, 500);
}
for (const [id, action] of [["confirm", "confirm"], ["pause", "pause"], ["resume", "resume"],
                            ["endfam", "end_familiarization"], ["abort", "abort"]]) {
  document.getElementById(id).addEventListener("click", async (ev) => {
    if (action === "abort" && !confirm("Abort the session? Data so far is kept; continue later with --resume.")) return;
    await fetch("/api/operator/" + action, {method: "POST", headers: H, body: "{}"});
    ev.target.blur();
  });
}
poll();
