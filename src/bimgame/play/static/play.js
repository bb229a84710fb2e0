// bimgame play: shows the frames the server sends, sends the keys held (protocol: bimgame/play/protocol.py).
"use strict";

const KEYS = {
  ArrowUp: "up", KeyW: "up", ArrowDown: "down", KeyS: "down",
  ArrowLeft: "left", KeyA: "left", ArrowRight: "right", KeyD: "right", Space: "noop",
};
const $ = (id) => document.getElementById(id);
const canvas = $("view");
const ctx = canvas.getContext("2d");

// What tests and curious people can read: frames drawn, frames per second, the last state and errors.
const play = (window.bimgamePlay = { frames: 0, fps: 0, state: null, hello: null, errors: [], connected: false });

let ws = null;
let heldCodes = [];   // key codes held, in press order
let sentHeld = "[]";
let stopped = false;
let decoding = false;
let pendingFrame = null;
const drawTimes = [];

function send(message) {
  if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify(message));
}

function heldNames() {
  const names = [];
  for (const code of heldCodes) if (!names.includes(KEYS[code])) names.push(KEYS[code]);
  return names;
}

function sendHeld() {
  const held = heldNames();
  const text = JSON.stringify(held);
  if (text === sentHeld) return;
  sentHeld = text;
  send({ type: "keys", held });
}

function releaseAll() {
  heldCodes = [];
  sendHeld();
}

function toggleControl() {
  if (!play.state || !play.state.agent) return;
  send({ type: "control", who: play.state.controller === "agent" ? "human" : "agent" });
}

function setGreedy(value) {
  send({ type: "greedy", value });
}

document.addEventListener("keydown", (event) => {
  if (event.ctrlKey || event.metaKey || event.altKey) return;
  if (event.code in KEYS) {
    event.preventDefault();
    if (!heldCodes.includes(event.code)) heldCodes.push(event.code);
    sendHeld();  // repeats of a held key change nothing and send nothing
  } else if (!event.repeat && event.code === "KeyR") {
    send({ type: "reset" });
  } else if (!event.repeat && event.code === "KeyH") {
    toggleControl();
  } else if (!event.repeat && event.code === "KeyG" && play.state && play.state.agent && play.state.agent.greedy !== null) {
    setGreedy(!play.state.agent.greedy);
  }
});
document.addEventListener("keyup", (event) => {
  if (event.code in KEYS) {
    event.preventDefault();
    heldCodes = heldCodes.filter((code) => code !== event.code);
    sendHeld();
  }
});
window.addEventListener("blur", releaseAll);  // keys released while the page had no focus never send keyup
document.addEventListener("visibilitychange", () => { if (document.hidden) releaseAll(); });

$("reset").addEventListener("click", (event) => { send({ type: "reset" }); event.target.blur(); });
$("control").addEventListener("click", (event) => { toggleControl(); event.target.blur(); });
$("greedy").addEventListener("change", (event) => { setGreedy(event.target.checked); event.target.blur(); });

function drawFrame(data) {
  if (decoding) { pendingFrame = data; return; }  // keep only the newest frame while one decodes
  decoding = true;
  createImageBitmap(new Blob([data], { type: "image/jpeg" })).then((bitmap) => {
    ctx.drawImage(bitmap, 0, 0, canvas.width, canvas.height);
    bitmap.close();
    play.frames += 1;
    const now = performance.now();
    drawTimes.push(now);
    while (drawTimes.length && drawTimes[0] < now - 2000) drawTimes.shift();
    play.fps = drawTimes.length > 1 ? (1000 * (drawTimes.length - 1)) / (now - drawTimes[0]) : 0;
  }).catch((error) => {
    play.errors.push(String(error));
  }).finally(() => {
    decoding = false;
    if (pendingFrame) { const next = pendingFrame; pendingFrame = null; drawFrame(next); }
  });
}

// Why an episode ended, as the end screen says it (the labyrinth's marble also falls or strays).
const ENDINGS = { hole: "into a hole!", "off the path": "off the path", "time limit": "time is up" };

function overlayText(s) {
  if (!play.connected) return stopped ? "the server stopped" : "connecting…";
  if (s.phase === "ready") {
    return s.controller === "human" ? "press an arrow key to start" : "";
  }
  if (s.phase === "over") {
    if (s.last && s.last.reason === "goal") return `success! score ${s.score}`;
    return (s.last && ENDINGS[s.last.reason]) || "time is up";
  }
  return "";
}

function showHello(h) {
  play.hello = h;
  const labyrinth = h.puzzle === "labyrinth";
  $("title").textContent = labyrinth ? "Labyrinth" : "Ball-in-Maze";
  document.title = `bimgame play — ${labyrinth ? "CyberRunner's labyrinth" : "Ball-in-Maze"}`;
  $("gauge-note").hidden = labyrinth;  // the labyrinth's frame has no tilt gauge: the panel shows the tilt
}

function showState(s) {
  play.state = s;
  $("task").textContent = s.task;
  $("score").textContent = String(s.score);
  $("step").textContent = `${s.step} / ${s.max_steps}`;
  $("success").textContent = s.success ? "yes" : "no";
  $("success").className = s.success ? "ok" : "";
  const expert = s.agent && s.agent.greedy === null;  // the MPC expert: no greedy/sampled switch
  $("controller").textContent = s.controller !== "agent" ? "you"
    : expert ? "agent (MPC expert)" : `agent (${s.agent.greedy ? "greedy" : "sampled"})`;
  const labyrinth = s.puzzle === "labyrinth";
  $("progress-row").hidden = !labyrinth;
  $("tilt-row").hidden = !labyrinth;
  if (labyrinth) {
    $("progress").textContent = `${(100 * s.progress).toFixed(1)} %`;
    $("tilt").textContent = `x ${s.tilt_deg[0].toFixed(1)}°, y ${s.tilt_deg[1].toFixed(1)}°`;
  }
  $("action").textContent = s.action;
  $("fps").textContent = `${play.fps.toFixed(1)} (server ${s.server_hz.toFixed(1)} Hz)`;
  $("clients").textContent = String(s.clients);
  $("overlay").textContent = overlayText(s);
  const control = $("control");
  control.hidden = !s.agent;
  $("greedy-label").hidden = !s.agent || expert;
  if (s.agent) {
    control.textContent = s.controller === "agent" ? "Take over (H)" : "Give to the agent (H)";
    if (!expert) $("greedy").checked = s.agent.greedy;
  }
  const rec = s.recording;
  $("recording").hidden = !rec;
  if (rec) {
    const now = s.controller === "human" && s.phase === "running" ? `● recording this episode (${s.recorded_steps} steps)`
      : "○ recording (only your own steps)";
    const problem = rec.session_error || rec.error;
    $("recording").textContent = `${now} — ${rec.episodes} episodes saved in ${rec.dir}` +
      (rec.built < rec.episodes ? " (dataset updating…)" : "") + (problem ? ` — ${problem}` : "");
  }
  if (s.last) {
    const l = s.last;
    $("last").textContent = `last episode: ${l.reason}, score ${l.score}, ${l.steps} steps` +
      (l.recorded !== null && l.recorded !== undefined ? `, recorded as episode ${l.recorded}` : "");
  }
}

function connect() {
  const url = `${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws`;
  ws = new WebSocket(url);
  ws.binaryType = "arraybuffer";
  ws.onopen = () => { play.connected = true; sentHeld = "[]"; sendHeld(); $("error").textContent = ""; };
  ws.onmessage = (event) => {
    if (typeof event.data !== "string") { drawFrame(event.data); return; }
    const message = JSON.parse(event.data);
    if (message.type === "state") showState(message);
    else if (message.type === "hello") showHello(message);
    else if (message.type === "error") {
      play.errors.push(message.message);
      $("error").textContent = `server: ${message.message}`;
    } else if (message.type === "bye") {
      stopped = true;
      $("error").textContent = message.message;
    }
  };
  ws.onclose = () => {
    play.connected = false;
    $("overlay").textContent = overlayText(play.state || {});
    if (!stopped) setTimeout(connect, 1000);
  };
}

connect();
