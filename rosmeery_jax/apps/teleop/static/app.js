// The teleop page: held keys go to the server at 10 Hz; state and images refresh at ~4 Hz.
"use strict";
const held = new Set();
const DRIVE = ["ArrowUp", "ArrowDown", "ArrowLeft", "ArrowRight", "w", "a", "s", "d", "W", "A", "S", "D"];
const COLORS = ["#1f77b4", "#d62728", "#ff7f0e", "#2ca02c", "#9467bd", "#8c564b"];
let running = true;

window.addEventListener("keydown", (e) => { if (DRIVE.includes(e.key)) { held.add(e.key); e.preventDefault(); } });
window.addEventListener("keyup", (e) => { held.delete(e.key); });
window.addEventListener("blur", () => held.clear());

function post(path, body) {
  return fetch(path, { method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body) });
}

setInterval(() => { if (running) post("/command", { keys: [...held] }).catch(() => {}); }, 100);

function drawCurves(state) {
  const c = document.getElementById("curves"), g = c.getContext("2d");
  g.clearRect(0, 0, c.width, c.height);
  g.strokeStyle = "#ccc"; g.strokeRect(0.5, 0.5, c.width - 1, c.height - 1);
  const h = state.history;
  if (h.length < 2) return;
  const t0 = h[0][0], t1 = Math.max(h[h.length - 1][0], t0 + 1);
  state.metric_names.forEach((name, k) => {
    g.strokeStyle = COLORS[k % COLORS.length]; g.beginPath();
    h.forEach((row, i) => {
      const x = (row[0] - t0) / (t1 - t0) * (c.width - 4) + 2, y = (1 - row[k + 1]) * (c.height - 4) + 2;
      if (i === 0) g.moveTo(x, y); else g.lineTo(x, y);
    });
    g.stroke();
  });
}

function render(state) {
  window.lastState = state;  // for tests and the console
  document.getElementById("title").textContent = state.title;
  document.getElementById("t").textContent = state.t.toFixed(1);
  document.getElementById("pose").textContent =
    `x ${state.pose[0].toFixed(2)} y ${state.pose[1].toFixed(2)} yaw ${state.pose[2].toFixed(2)}`;
  document.getElementById("rec").textContent = state.recording ? `recording to ${state.recording}` : "not recording";
  // Blind view (the paper's human baseline): only the map and the camera, no scores or labels.
  document.querySelectorAll(".scores").forEach((el) => { el.hidden = state.view === "blind"; });
  if (state.view !== "blind") renderScores(state);
  const stamp = `?step=${state.step}`;
  for (const id of ["map", "rgb", "depth"]) {
    const img = document.getElementById(id);
    if (img.dataset.step !== String(state.step)) { img.src = `/${id}.png${stamp}`; img.dataset.step = state.step; }
  }
  document.body.dataset.step = state.step;
  if (!state.running) { running = false; document.getElementById("status").append(" — session stopped."); }
}

function renderScores(state) {
  document.getElementById("metrics").innerHTML = state.metric_names.map((m, k) =>
    `<tr><td style="color:${COLORS[k % COLORS.length]}">■ ${m}</td><td class="num">${state.metrics[m].toFixed(3)}</td></tr>`).join("");
  document.getElementById("nlab").textContent = `${state.labels.length} of ${state.objects}`;
  document.querySelector("#labels table").innerHTML = "<tr><th>label</th><th>object</th><th>conf.</th></tr>" +
    state.labels.map((l) => `<tr><td>${l.label}</td><td>${l.object}</td><td class="num">${l.confidence.toFixed(2)}</td></tr>`).join("");
  drawCurves(state);
}

async function poll() {
  try {
    const state = await (await fetch("/state")).json();
    render(state);
  } catch (e) { /* server gone: keep the last view */ }
  if (running) setTimeout(poll, 250);
}

document.getElementById("stop").addEventListener("click", async () => {
  running = false;
  const state = await (await post("/stop", {})).json();
  render(state);
});
poll();
