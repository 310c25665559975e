// choreo studio: five pages over the REST and WebSocket API, one 3D stage.
import * as api from "./api.js";
import { framePositions, motionPositions } from "./fk.js";
import { drawPlot } from "./plot.js";
import { Player, Stage } from "./viewer.js";

const BLUE = 0x4ea1ff;
const ORANGE = 0xff9f43;
const GREY = 0x9aa3b2;
/** Query windows are counted at 60 fps (the API's `frames`). */
const QUERY_FPS = 60;

const $ = (sel, root = document) => root.querySelector(sel);
const esc = (s) =>
  String(s ?? "").replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" })[c]);

// What the browser tests and the benchmark read (no effect on the page).
window.__studio = { ready: false, page: null, errors: [], firstFrameMs: null, streamed: 0, playerTime: 0, fk: framePositions };

const panel = $("#panel");
const stage = new Stage($("#stage"));
const player = new Player(stage, $("#player"));
const plot = $("#plot");
let motions = []; // the archive's summaries
let model = null; // GET /v1/model, or the error why not
let closeSocket = null; // the open stream's stopper, if any
let plotState = null;

stage.onFrame.push(() => {
  window.__studio.framesDrawn = stage.framesDrawn;
  if (plotState) drawPlot(plot, plotState, player.t);
});

// ---------------------------------------------------------------- errors

function showError(e) {
  const box = $("#error");
  box.textContent = e instanceof Error ? e.message : String(e);
  box.hidden = false;
  window.__studio.errors.push(box.textContent);
}

function clearError() {
  $("#error").hidden = true;
}

/** Run an action, its failure shown in the page (never a blank screen). */
async function attempt(fn) {
  clearError();
  try {
    return await fn();
  } catch (e) {
    showError(e);
    return undefined;
  }
}

// ---------------------------------------------------------------- motion helpers

const cache = new Map();

/** A stored motion with its skeleton and every frame's joint positions. */
async function loadMotion(id) {
  if (cache.has(id)) return cache.get(id);
  const m = await api.get(`/v1/motions/${id}`);
  const full = { summary: m.summary, data: m.motion, skeleton: m.skeleton, frames: motionPositions(m.skeleton, m.motion) };
  cache.set(id, full);
  return full;
}

/** x, z that bring the root of `frames[start]` over the origin, plus `dx`. */
function centre(frames, start, dx) {
  const f = frames[Math.min(start, frames.length - 1)];
  return [dx - f[0], -f[2]];
}

function legend(items) {
  $("#legend").innerHTML = items
    .map(([c, t]) => `<span><i style="background:#${c.toString(16).padStart(6, "0")}"></i>${esc(t)}</span>`)
    .join("");
}

/** Show clips on the stage: `[{motion frames, fps, color, start, length, dx, label}]`. */
function showClips(specs, { play = true, centred = true } = {}) {
  stage.clear();
  const clips = specs.map((s) => {
    const start = s.start || 0;
    const length = s.length ?? s.frames.length - start;
    const shift = centred && s.frames.length ? centre(s.frames, start, s.dx || 0) : [s.dx || 0, 0];
    const rig = stage.addRig(s.skeleton, s.color, shift);
    return { rig, fps: s.fps, frames: s.frames, start, length };
  });
  player.live = false;
  player.setClips(clips, { play });
  stage.frame(clips.filter((c) => c.length).map((c) => ({ pos: c.frames[c.start], shift: c.rig.shift })));
  legend(specs.map((s) => [s.color, s.label]));
  return clips;
}

function labelText(labels) {
  return Object.entries(labels || {})
    .map(([k, v]) => `${k}=${v}`)
    .join(" ");
}

function motionName(m) {
  const base = (m.source_path || "").split("/").pop() || `motion ${m.id}`;
  return base;
}

function motionOptions(filter = () => true) {
  return motions
    .filter(filter)
    .map((m) => `<option value="${m.id}">#${m.id} ${esc(motionName(m))} (${m.duration_s.toFixed(1)} s)</option>`)
    .join("");
}

async function refreshMotions() {
  motions = (await api.get("/v1/motions")).motions;
  return motions;
}

async function loadModel() {
  if (model) return model;
  try {
    model = await api.get("/v1/model");
  } catch (e) {
    model = { error: e };
  }
  return model;
}

function stopStream() {
  if (closeSocket) closeSocket();
  closeSocket = null;
}

function setPlot(state) {
  plotState = state;
  plot.hidden = !state;
  stage.resize();
}

// ---------------------------------------------------------------- Archive

async function archivePage() {
  panel.innerHTML = `
    <h2>Archive</h2>
    <div class="row"><label for="f-kind">label</label>
      <select id="f-kind"><option value="">any kind</option></select>
      <select id="f-value"><option value="">any value</option></select></div>
    <div class="row"><label for="f-text">name</label><input id="f-text" placeholder="filter by name"></div>
    <ul id="motion-list" class="list"></ul>
    <div id="details"></div>
    <h3>Upload</h3>
    <div class="row"><input id="up-file" type="file" aria-label="motion file"></div>
    <div class="row"><label for="up-labels">labels</label><input id="up-labels" placeholder="genre=BR dancer=d01"></div>
    <div class="row"><button id="up-go" type="button">upload</button><span id="up-result" class="note"></span></div>
    <p class="note">.pkl (AIST++), .npz (AMASS), .bvh, .json (choreo motion). Uploading needs a write token.</p>`;
  await refreshMotions();
  const kinds = [...new Set(motions.flatMap((m) => Object.keys(m.labels || {})))].sort();
  $("#f-kind").innerHTML += kinds.map((k) => `<option>${esc(k)}</option>`).join("");
  const renderList = () => {
    const kind = $("#f-kind").value;
    const value = $("#f-value").value;
    const text = $("#f-text").value.toLowerCase();
    const shown = motions.filter(
      (m) =>
        (!kind || (m.labels || {})[kind] !== undefined) &&
        (!value || (m.labels || {})[kind] === value) &&
        (!text || motionName(m).toLowerCase().includes(text)),
    );
    $("#motion-list").innerHTML = shown
      .map(
        (m) => `<li data-id="${m.id}"><b>#${m.id}</b> ${esc(motionName(m))}
          <div class="meta">${m.duration_s.toFixed(1)} s · ${m.fps} fps · ${esc(labelText(m.labels))}</div></li>`,
      )
      .join("") || `<li class="meta">no motion matches</li>`;
  };
  $("#f-kind").onchange = () => {
    const kind = $("#f-kind").value;
    const values = [...new Set(motions.map((m) => (m.labels || {})[kind]).filter((v) => v !== undefined))].sort();
    $("#f-value").innerHTML = `<option value="">any value</option>` + values.map((v) => `<option>${esc(v)}</option>`).join("");
    renderList();
  };
  $("#f-value").onchange = renderList;
  $("#f-text").oninput = renderList;
  $("#motion-list").onclick = (e) => {
    const li = e.target.closest("li[data-id]");
    if (!li) return;
    for (const x of $("#motion-list").children) x.classList.toggle("active", x === li);
    attempt(() => playStored(Number(li.dataset.id)));
  };
  $("#up-go").onclick = () => attempt(upload);
  renderList();
  if (motions.length) await playStored(motions[0].id, false);
}

async function playStored(id, play = true) {
  const m = await loadMotion(id);
  showClips([{ frames: m.frames, fps: m.data.fps, skeleton: m.skeleton, color: BLUE, label: motionName(m.summary) }], {
    play,
    centred: false,
  });
  const s = m.summary;
  $("#details").innerHTML = `
    <dl><dt>id</dt><dd>${s.id}</dd><dt>source</dt><dd>${esc(s.source_path)}</dd>
    <dt>frames</dt><dd>${s.frames} at ${s.fps} fps (${s.duration_s.toFixed(2)} s)</dd>
    <dt>skeleton</dt><dd>${esc(s.skeleton)}, ${s.joints} joints</dd>
    <dt>labels</dt><dd>${esc(labelText(s.labels)) || "—"}</dd>
    ${s.video ? `<dt>video</dt><dd>${esc(s.video)}</dd>` : ""}</dl>
    <div class="row"><button id="ex-bvh" type="button">export BVH</button>
      <button id="ex-glb" type="button">export glb</button></div>`;
  const stem = motionName(s).replace(/\.[^.]+$/, "");
  $("#ex-bvh").onclick = () => attempt(() => api.download(`/v1/motions/${id}/bvh`, `${stem}.bvh`));
  $("#ex-glb").onclick = () => attempt(() => api.download(`/v1/motions/${id}/glb`, `${stem}.glb`));
}

async function upload() {
  const file = $("#up-file").files[0];
  if (!file) throw new Error("choose a file to upload first");
  const labels = {};
  for (const kv of $("#up-labels").value.split(/\s+/).filter(Boolean)) {
    const [k, v] = kv.split("=", 2);
    if (!k || v === undefined) throw new Error(`labels: "${kv}" is not kind=value`);
    labels[k] = v;
  }
  $("#up-result").textContent = "uploading…";
  try {
    const r = await api.post("/v1/motions", {
      motion: { file: { name: file.name, content_base64: await api.fileBase64(file) } },
      labels,
    });
    $("#up-result").innerHTML = `<span class="ok">${r.status === "new" ? "stored" : "already stored"} as #${r.motion_id}</span>`;
    cache.delete(r.motion_id);
    await archivePage();
    await playStored(r.motion_id);
  } catch (e) {
    $("#up-result").textContent = "";
    throw e;
  }
}

// ---------------------------------------------------------------- Search

async function searchPage() {
  panel.innerHTML = `
    <h2>Search</h2>
    <div class="row"><label for="q-motion">motion</label><select id="q-motion"></select></div>
    <div class="row"><label for="q-start">from (s)</label><input id="q-start" type="number" min="0" step="0.5" value="2"></div>
    <div class="row"><label for="q-len">length (s)</label><input id="q-len" type="number" min="2.14" step="0.5" value="4"></div>
    <div class="row"><label for="q-k">hits</label><input id="q-k" type="number" min="1" max="100" value="10"></div>
    <div class="row"><label for="q-emb">embedding</label><select id="q-emb">
      <option value="">default</option><option>stft</option><option>dct</option><option>pca</option><option>pose</option></select></div>
    <div class="row"><button id="q-go" class="primary" type="button">search</button></div>
    <ul id="hits" class="list"></ul>
    <p class="note">Pick a hit to play it (orange) beside the query (blue), in step.</p>`;
  await refreshMotions();
  $("#q-motion").innerHTML = motionOptions();
  $("#q-go").onclick = () => attempt(search);
}

async function search() {
  const id = Number($("#q-motion").value);
  const start = Number($("#q-start").value);
  const seconds = Number($("#q-len").value);
  const frames = Math.max(128, Math.round(seconds * QUERY_FPS));
  const body = { motion: { id }, start_s: start, frames, k: Number($("#q-k").value) };
  if ($("#q-emb").value) body.embedding = $("#q-emb").value;
  const [r, query] = await Promise.all([api.post("/v1/query", body), loadMotion(id)]);
  const list = $("#hits");
  list.innerHTML =
    r.hits
      .map(
        (h, i) => `<li data-i="${i}"><span class="score">${h.score.toFixed(3)}</span>
        <b>${i + 1}.</b> #${h.motion_id} ${esc(h.source_path.split("/").pop())}
        <div class="meta">from ${h.start_s.toFixed(2)} s · ${esc(labelText(h.labels))}</div></li>`,
      )
      .join("") || `<li class="meta">no hits</li>`;
  const dur = frames / QUERY_FPS;
  const playHit = async (i) => {
    const h = r.hits[i];
    const hit = await loadMotion(h.motion_id);
    const qf = query.data.fps;
    const hf = hit.data.fps;
    showClips([
      { frames: query.frames, fps: qf, skeleton: query.skeleton, color: BLUE, start: Math.round(start * qf),
        length: Math.min(Math.round(dur * qf), query.frames.length - Math.round(start * qf)), dx: -0.9, label: "query" },
      { frames: hit.frames, fps: hf, skeleton: hit.skeleton, color: ORANGE, start: Math.round(h.start_s * hf),
        length: Math.min(Math.round(dur * hf), hit.frames.length - Math.round(h.start_s * hf)), dx: 0.9,
        label: `hit ${i + 1}: #${h.motion_id} (${h.score.toFixed(3)})` },
    ]);
    for (const x of list.children) x.classList.toggle("active", Number(x.dataset.i) === i);
  };
  list.onclick = (e) => {
    const li = e.target.closest("li[data-i]");
    if (li) attempt(() => playHit(Number(li.dataset.i)));
  };
  if (r.hits.length) await playHit(0);
}

// ---------------------------------------------------------------- Generate

function labelSelects(m, prefix) {
  return Object.entries(m.labels || {})
    .filter(([k]) => (m.conditioned_on || []).includes(k))
    .map(
      ([k, vs]) => `<div class="row"><label for="${prefix}-${k}">${esc(k)}</label>
      <select id="${prefix}-${k}" data-kind="${esc(k)}"><option value="">—</option>${vs
        .map((v) => `<option>${esc(v)}</option>`)
        .join("")}</select></div>`,
    )
    .join("");
}

function chosenLabels(prefix) {
  const out = {};
  for (const s of panel.querySelectorAll(`select[id^="${prefix}-"][data-kind]`)) if (s.value) out[s.dataset.kind] = s.value;
  return out;
}

function samplingFields(prefix) {
  return `<h3>Sampling</h3>
    <div class="row"><label for="${prefix}-temp">temperature</label><input id="${prefix}-temp" type="number" step="0.05" min="0" placeholder="1"></div>
    <div class="row"><label for="${prefix}-topp">top-p</label><input id="${prefix}-topp" type="number" step="0.01" min="0.01" max="1" placeholder="0.95"></div>
    <div class="row"><label for="${prefix}-seed">seed</label><input id="${prefix}-seed" type="number" step="1" min="0" placeholder="random"></div>`;
}

function chosenSampling(prefix) {
  const s = {};
  const num = (id) => ($(id).value === "" ? undefined : Number($(id).value));
  if (num(`#${prefix}-temp`) !== undefined) s.temperature = num(`#${prefix}-temp`);
  if (num(`#${prefix}-topp`) !== undefined) s.top_p = num(`#${prefix}-topp`);
  if (num(`#${prefix}-seed`) !== undefined) s.seed = num(`#${prefix}-seed`);
  return s;
}

function jointBoxes(m, prefix, checked = []) {
  return `<div class="joints">${m.prompt_joints
    .map(
      (j) => `<label><input type="checkbox" name="${prefix}-joint" value="${esc(j)}" ${checked.includes(j) ? "checked" : ""}> ${esc(j)}</label>`,
    )
    .join("")}</div>`;
}

function chosenJoints(prefix) {
  return [...panel.querySelectorAll(`input[name="${prefix}-joint"]:checked`)].map((x) => x.value);
}

function modelMissing(m) {
  panel.innerHTML += `<p class="note">No model is available: ${esc(m.error.message)}</p>`;
}

async function generatePage() {
  const m = await loadModel();
  panel.innerHTML = `<h2>Generate</h2>`;
  if (m.error) return modelMissing(m);
  await refreshMotions();
  panel.innerHTML += `
    <p class="note">${esc(m.kind)} · ${m.fps} fps · ${m.context_frames} frames of context</p>
    <h3>Labels</h3>${labelSelects(m, "g")}
    <div class="row"><label for="g-seconds">seconds</label><input id="g-seconds" type="number" min="0.5" max="${m.max_frames / m.fps}" step="0.5" value="10"></div>
    ${samplingFields("g")}
    <div class="row"><label for="g-steer">steer to the labels</label><input id="g-steer" type="checkbox">
      <span class="note">every 20 frames, 4 continuations; the model's class heads keep the likeliest (4× the work)</span></div>
    ${m.postures ? `<div class="row"><label for="g-posture">posture</label><select id="g-posture">
        <option value="">the labels' default</option><option value="hold">hold the style</option><option value="free">free</option></select>
      <span class="note">hold: pull every joint and the body's tilt toward the labels' own posture, changes capped at 12° a frame (keeps the label to the end); free: no pull (livelier, the label fades); the default holds Bandai styles and contents and AIST++ genres</span></div>` : ""}
    ${m.kind === "motion-frame-lm" ? `<div class="row"><label for="g-keep">keep the label</label><input id="g-keep" type="checkbox">
      <span class="note">the model reads only the last 1 s it made, so the labels weigh more: the clip holds its style longer, and moves less</span></div>` : ""}
    <div class="row"><label for="g-feet">feet on the floor</label><input id="g-feet" type="checkbox">
      <span class="note">the root travels as the planted foot says, so feet do not slide (the model's own path in the air)</span></div>
    <div class="row"><label for="g-pin">pin the feet</label><input id="g-pin" type="checkbox">
      <span class="note">a foot that comes down stays where it touched until it lifts (hips and knees re-solved); for dancing in place, or with feet on the floor</span></div>
    <h3>Prompt joints</h3>
    <div class="row"><label for="g-prompt">from</label><select id="g-prompt"><option value="">no prompt</option>${motionOptions()}</select></div>
    ${jointBoxes(m, "g")}
    <div class="row"><button id="g-go" class="primary" type="button">generate</button>
      <button id="g-stop" type="button" disabled>stop</button>
      <button id="g-save" type="button" disabled>download JSON</button></div>
    <div id="g-status" class="note"></div>`;
  $("#g-go").onclick = () => attempt(generate);
  $("#g-stop").onclick = stopStream;
}

async function generate() {
  stopStream();
  const m = model;
  const clicked = performance.now();
  const frames = Math.round(Number($("#g-seconds").value) * m.fps);
  const body = { labels: chosenLabels("g"), frames, sampling: chosenSampling("g") };
  if ($("#g-steer").checked) {
    body.candidates = 4;
    body.rank_every = 20;
  }
  const posture = $("#g-posture")?.value;
  if (posture === "hold") {
    body.sampling.posture = 2;
    body.sampling.max_jump = 12;
  } else if (posture === "free") {
    body.sampling.posture = 0;
  }
  if ($("#g-keep")?.checked) body.sampling.context = 20;
  if ($("#g-feet").checked) body.root = "feet";
  if ($("#g-pin").checked) body.feet = "pin";
  const promptId = $("#g-prompt").value;
  const joints = chosenJoints("g");
  let prompt = null;
  if (promptId) {
    if (!joints.length) throw new Error("prompt joints: tick the joints to take from the prompt motion");
    body.prompt = { id: Number(promptId) };
    body.prompt_joints = joints;
    prompt = await loadMotion(Number(promptId));
  } else if (joints.length) {
    throw new Error("prompt: choose the motion the ticked joints come from");
  }
  const out = { fps: m.fps, skeleton: m.skeleton.kind, rotations: [], translation: [], labels: body.labels, name: "generated" };
  const frameList = [];
  const specs = [{ frames: frameList, fps: m.fps, skeleton: m.skeleton, color: ORANGE, dx: prompt ? 0.9 : 0, label: "generated" }];
  if (prompt) specs.push({ frames: prompt.frames, fps: prompt.data.fps, skeleton: prompt.skeleton, color: GREY, dx: -0.9, label: "prompt" });
  stage.clear();
  const clips = specs.map((s) => ({ rig: stage.addRig(s.skeleton, s.color, [s.dx, 0]), fps: s.fps, frames: s.frames, start: 0, length: 0 }));
  legend(specs.map((s) => [s.color, s.label]));
  player.setClips(clips);
  player.live = true;
  window.__studio.firstFrameMs = null;
  window.__studio.streamed = 0;
  const status = $("#g-status");
  status.textContent = "connecting…";
  $("#g-stop").disabled = false;
  $("#g-save").disabled = true;
  const ws = api.socket("/v1/generate/ws");
  let root0 = null;
  let finished = false;
  let exemplarNote = "";
  closeSocket = () => {
    finished = true;
    ws.close();
    $("#g-stop").disabled = true;
    player.live = false;
  };
  const timing = (window.__studio.timing = { setup: performance.now() - clicked });
  ws.onopen = () => {
    timing.open = performance.now() - clicked;
    ws.send(JSON.stringify(body));
  };
  ws.onmessage = (ev) => {
    const msg = JSON.parse(ev.data);
    if (msg.start) {
      timing.start = performance.now() - clicked;
      // The style exemplar the model continues (context only, not shown).
      const ex = msg.start.exemplar;
      exemplarNote = ex ? ` · continuing ${ex.seconds.toFixed(1)} s of ${ex.source} (style exemplar)` : "";
      // The sampling that runs, the server's defaults filled in.
      const s = msg.start.sampling;
      if (s) exemplarNote += ` · t ${s.temperature}, top-p ${s.top_p}, keep ±${s.keep_near}, max jump ${s.max_jump}`;
      window.__studio.exemplar = ex || null;
      window.__studio.sampling = s || null;
    }
    if (msg.frame && timing.frame === undefined) timing.frame = performance.now() - clicked;
    if (msg.error) {
      finished = true;
      showError(new api.ApiError(0, msg).message.replace(/^0 /, ""));
      status.textContent = "stopped";
      player.live = false;
      return;
    }
    if (msg.frame) {
      const f = msg.frame;
      out.rotations.push(f.rotations);
      out.translation.push(f.translation);
      const pos = framePositions(m.skeleton, f.rotations, f.translation);
      if (!root0) {
        root0 = [pos[0], pos[2]];
        clips[0].rig.shift = [(prompt ? 0.9 : 0) - root0[0], -root0[1]];
        if (prompt) clips[1].rig.shift = centre(prompt.frames, 0, -0.9);
        stage.frame([{ pos, shift: clips[0].rig.shift }]);
      }
      frameList.push(pos);
      clips[0].length = frameList.length;
      if (prompt) clips[1].length = Math.min(prompt.frames.length, Math.round((frameList.length / m.fps) * prompt.data.fps));
      window.__studio.streamed = frameList.length;
      if (window.__studio.firstFrameMs === null) {
        // Drawn on the next animation frame: the click-to-motion latency.
        requestAnimationFrame(() => {
          if (window.__studio.firstFrameMs === null) window.__studio.firstFrameMs = performance.now() - clicked;
        });
      }
      status.textContent = `${frameList.length} / ${frames} frames · ${f.latency_ms.toFixed(1)} ms per frame${exemplarNote}`;
    } else if (msg.end) {
      finished = true;
      player.live = false;
      status.innerHTML = `<span class="ok">${msg.end.frames} frames in ${msg.end.seconds.toFixed(2)} s</span>`;
      status.append(exemplarNote);
      if (window.__studio.firstFrameMs !== null)
        status.append(` · first frame shown ${window.__studio.firstFrameMs.toFixed(0)} ms after the click`);
      $("#g-stop").disabled = true;
      $("#g-save").disabled = false;
      $("#g-save").onclick = () =>
        api.saveBlob(new Blob([JSON.stringify(out)], { type: "application/json" }), "generated.json");
    }
  };
  ws.onerror = () => {
    if (!finished) showError("the generation stream failed (is the server up, and the token right?)");
  };
  ws.onclose = (ev) => {
    if (!finished && ev.code !== 1000) showError(`the stream closed early (${ev.code} ${ev.reason || ""})`);
    finished = true;
    player.live = false;
  };
}

// ---------------------------------------------------------------- Keyframes

async function keyframesPage() {
  const m = await loadModel();
  await refreshMotions();
  panel.innerHTML = `
    <h2>Keyframes</h2>
    <div class="row"><label for="k-motion">motion</label><select id="k-motion">${motionOptions()}</select></div>
    <div class="row"><label for="k-count">keyframes</label><input id="k-count" type="number" min="2" value="40"></div>
    <div class="row"><label for="k-select">chosen by</label><select id="k-select">
      <option value="dp">dynamic programming</option><option value="even">even spacing</option></select></div>
    <div class="row"><label for="k-between">in-betweens</label><select id="k-between">
      <option value="slerp">SLERP</option><option value="bezier">Bézier</option><option value="catmull-rom">Catmull-Rom</option>
      ${m && !m.error && m.inbetweener ? `<option value="learned">learned</option>` : ""}</select></div>
    <div class="row"><button id="k-go" class="primary" type="button">rebuild</button></div>
    <div id="k-result" class="note"></div>
    <p class="note">The original (blue) and the rebuild (orange) are overlaid; below, the error per frame, keyframes marked.</p>`;
  $("#k-go").onclick = () => attempt(rebuild);
}

async function rebuild() {
  const id = Number($("#k-motion").value);
  const body = { motion: { id }, count: Number($("#k-count").value), select: $("#k-select").value, inbetween: $("#k-between").value };
  const [r, orig] = await Promise.all([api.post("/v1/keyframes", body), loadMotion(id)]);
  const rebuilt = motionPositions(orig.skeleton, r.output);
  showClips(
    [
      { frames: orig.frames, fps: orig.data.fps, skeleton: orig.skeleton, color: BLUE, label: "original" },
      { frames: rebuilt, fps: r.output.fps, skeleton: orig.skeleton, color: ORANGE, label: `rebuilt (${body.inbetween})` },
    ],
    { centred: false },
  );
  setPlot({ values: r.per_frame_error, fps: r.fps, marks: r.keyframes, label: "per-frame error" });
  $("#k-result").innerHTML = `${r.keyframes.length} keyframes of ${r.frames} frames · MSE <b>${r.mse.toExponential(3)}</b>`;
}

// ---------------------------------------------------------------- Duet

async function duetPage() {
  const m = await loadModel();
  panel.innerHTML = `<h2>Duet</h2>`;
  if (m.error) return modelMissing(m);
  await refreshMotions();
  const usable = (x) => x.skeleton === "smpl24" || x.skeleton === "smpl13";
  panel.innerHTML += `
    <p class="note">A stored motion dances as the performer (grey); its ticked joints lead, and the model's partner (orange) answers frame by frame over a WebSocket.</p>
    <div class="row"><label for="d-motion">performer</label><select id="d-motion">${motionOptions(usable)}</select></div>
    <div class="row"><label for="d-seconds">seconds</label><input id="d-seconds" type="number" min="1" max="60" value="10"></div>
    <h3>Labels</h3>${labelSelects(m, "d")}
    ${samplingFields("d")}
    <h3>Joints the performer leads</h3>
    ${jointBoxes(m, "d", [m.prompt_joints[0]])}
    <div class="row"><button id="d-go" class="primary" type="button">dance</button>
      <button id="d-stop" type="button" disabled>stop</button></div>
    <div id="d-status" class="note"></div>`;
  $("#d-go").onclick = () => attempt(duet);
  $("#d-stop").onclick = stopStream;
}

async function duet() {
  stopStream();
  const m = model;
  const perf = await loadMotion(Number($("#d-motion").value));
  const seconds = Number($("#d-seconds").value);
  const src = perf.data;
  // The performer at the model's frame rate (nearest source frame).
  const n = Math.min(Math.floor((src.rotations.length / src.fps) * m.fps), Math.round(seconds * m.fps));
  const idx = Array.from({ length: n }, (_, i) => Math.min(Math.round((i / m.fps) * src.fps), src.rotations.length - 1));
  const oneFrame = (i) => ({
    fps: m.fps,
    skeleton: src.skeleton || "smpl24",
    rotations: [src.rotations[idx[i]]],
    translation: [src.translation[idx[i]]],
  });
  const performerFrames = idx.map((i) => perf.frames[i]);
  const partnerFrames = [];
  window.__studio.streamed = 0;
  stage.clear();
  const perfRig = stage.addRig(perf.skeleton, GREY, centre(performerFrames, 0, -0.9));
  const partRig = stage.addRig(m.skeleton, ORANGE, [0.9, 0]);
  const clips = [
    { rig: perfRig, fps: m.fps, frames: performerFrames, start: 0, length: 0 },
    { rig: partRig, fps: m.fps, frames: partnerFrames, start: 0, length: 0 },
  ];
  legend([[GREY, "performer"], [ORANGE, "partner"]]);
  player.setClips(clips);
  player.live = true;
  stage.frame([{ pos: performerFrames[0], shift: perfRig.shift }]);
  const status = $("#d-status");
  const ws = api.socket("/v1/duet/ws");
  let sent = 0;
  let finished = false;
  const t0 = performance.now();
  const lat = [];
  let sentAt = 0;
  closeSocket = () => {
    finished = true;
    ws.close();
    player.live = false;
    $("#d-stop").disabled = true;
  };
  $("#d-stop").disabled = false;
  const sendNext = () => {
    if (finished || sent >= n) return;
    // Paced at the model's frame rate: frame i leaves at i / fps.
    const due = t0 + (sent / m.fps) * 1000;
    setTimeout(() => {
      if (finished) return;
      sentAt = performance.now();
      ws.send(JSON.stringify(sent === 0 ? { labels: chosenLabels("d"), prompt_joints: chosenJoints("d"), sampling: chosenSampling("d"), frame: oneFrame(0) } : { frame: oneFrame(sent) }));
      sent++;
    }, Math.max(0, due - performance.now()));
  };
  ws.onopen = sendNext;
  ws.onmessage = (ev) => {
    const msg = JSON.parse(ev.data);
    if (msg.error) {
      finished = true;
      player.live = false;
      showError(new api.ApiError(0, msg).message.replace(/^0 /, ""));
      return;
    }
    const f = msg.frame;
    lat.push(performance.now() - sentAt);
    const pos = framePositions(m.skeleton, f.rotations, f.translation);
    if (!partnerFrames.length) {
      partRig.shift = [0.9 - pos[0], -pos[2]];
      stage.frame([
        { pos: performerFrames[0], shift: perfRig.shift },
        { pos, shift: partRig.shift },
      ]);
    }
    partnerFrames.push(pos);
    clips[0].length = clips[1].length = partnerFrames.length;
    window.__studio.streamed = partnerFrames.length;
    const sorted = [...lat].sort((a, b) => a - b);
    status.textContent = `${partnerFrames.length} / ${n} frames · answer ${sorted[Math.floor(sorted.length / 2)].toFixed(1)} ms (median)`;
    if (partnerFrames.length >= n) {
      finished = true;
      ws.close(1000);
      player.live = false;
      $("#d-stop").disabled = true;
      status.innerHTML = `<span class="ok">${n} frames danced</span> · answer ${sorted[Math.floor(sorted.length / 2)].toFixed(1)} ms median`;
    } else sendNext();
  };
  ws.onclose = (ev) => {
    if (!finished && ev.code !== 1000) showError(`the duet closed early (${ev.code} ${ev.reason || ""})`);
    finished = true;
    player.live = false;
  };
}

// ---------------------------------------------------------------- routing

const pages = { archive: archivePage, search: searchPage, generate: generatePage, keyframes: keyframesPage, duet: duetPage };

async function route() {
  stopStream();
  setPlot(null);
  const page = (location.hash || "#archive").slice(1);
  const show = pages[page] ? page : "archive";
  for (const a of document.querySelectorAll("nav a")) a.classList.toggle("active", a.dataset.page === show);
  window.__studio.ready = false;
  window.__studio.page = show;
  window.__studio.streamed = 0;
  stage.clear();
  player.setClips([], { play: false });
  legend([]);
  await attempt(pages[show]);
  window.__studio.ready = true;
}

$("#token").value = api.token();
$("#token-form").onsubmit = (e) => {
  e.preventDefault();
  api.setToken($("#token").value.trim());
  cache.clear();
  model = null;
  route();
};
document.addEventListener("keydown", (e) => {
  if (e.code === "Space" && !["INPUT", "SELECT", "TEXTAREA", "BUTTON"].includes(document.activeElement.tagName)) {
    e.preventDefault();
    player.toggle();
  }
});
window.addEventListener("hashchange", route);
route();
