// Drives the web studio in Debian's Chromium (playwright-core, no browser
// download) against a running `choreo serve`, page by page, and prints one
// JSON object of measurements. Exits non-zero, naming the step, when a
// check fails. Run by tests/studio.rs; by hand:
//   node tests/browser/studio.mjs --url http://127.0.0.1:8080 --token T \
//     [--shots docs] [--fk-out fk.json] [--chromium /usr/bin/chromium]
// The server must allow the origin http://127.0.0.1:<--cors-port> and no
// other (`--cors-origin`), for the cross-origin checks.
import { createServer } from "node:http";
import { writeFileSync, readFileSync } from "node:fs";
import { createRequire } from "node:module";

const require = createRequire(new URL("../../web/package.json", import.meta.url));
const { chromium } = require("playwright-core");

const args = Object.fromEntries(
  process.argv.slice(2).reduce((acc, a, i, all) => (a.startsWith("--") ? [...acc, [a.slice(2), all[i + 1]]] : acc), []),
);
const url = args.url;
const token = args.token || "";
const shots = args.shots || null;
const corsPort = Number(args["cors-port"] || 0);
const results = {};
let step = "start";
const consoleErrors = [];
let allowResourceErrors = false;

function check(ok, what) {
  if (!ok) throw new Error(`${step}: ${what}`);
}

async function canvasStats(page, sel = "#stage canvas") {
  return page.evaluate((sel) => {
    const c = document.querySelector(sel);
    const o = document.createElement("canvas");
    o.width = c.width;
    o.height = c.height;
    const g = o.getContext("2d");
    g.drawImage(c, 0, 0);
    const d = g.getImageData(0, 0, c.width, c.height).data;
    let coloured = 0;
    let lit = 0;
    // Coloured pixels (the rigs: blue, orange) and bright ones (joints);
    // the background and the grid are dark and grey.
    for (let i = 0; i < d.length; i += 4) {
      const mx = Math.max(d[i], d[i + 1], d[i + 2]);
      const mn = Math.min(d[i], d[i + 1], d[i + 2]);
      if (mx - mn > 60) coloured++;
      if (mx > 150) lit++;
    }
    return { w: c.width, h: c.height, coloured, lit, pixels: Array.from(d.filter((_, i) => i % 4 === 0 && (i / 4) % 7 === 0)) };
  }, sel);
}

function changed(a, b) {
  let n = 0;
  for (let i = 0; i < a.pixels.length; i++) if (Math.abs(a.pixels[i] - b.pixels[i]) > 24) n++;
  return n;
}

async function drawsAndMoves(page, label) {
  const a = await canvasStats(page);
  check(a.coloured > 200, `the 3D canvas is blank (${a.coloured} coloured pixels of ${a.w}×${a.h})`);
  // Playing motion changes the picture within 0.4 s; a slower machine (or a
  // stream that holds at its newest frame while the server catches up, or a
  // dancer standing still for a moment) gets up to 4 s before it counts as
  // frozen.
  const streamedBefore = await page.evaluate(() => window.__studio.streamed);
  let n = 0;
  let waited = 0;
  while (waited < 4000) {
    await page.waitForTimeout(400);
    waited += 400;
    n = changed(a, await canvasStats(page));
    if (n > 50) break;
  }
  const streamedAfter = await page.evaluate(() => window.__studio.streamed);
  check(
    n > 50,
    `the 3D canvas does not change while playing (${n} pixels changed in ${waited / 1000} s; streamed frames ${streamedBefore} → ${streamedAfter})`,
  );
  results[`${label}_coloured_pixels`] = a.coloured;
  results[`${label}_changed_pixels`] = n;
  results[`${label}_moved_within_ms`] = waited;
}

async function ready(page) {
  await page.waitForFunction(() => window.__studio && window.__studio.ready, null, { timeout: 60000 });
}

async function goto(page, hash) {
  step = hash;
  await page.evaluate((h) => (location.hash = h), hash);
  await page.waitForFunction((h) => window.__studio.page === h.slice(1) && window.__studio.ready, hash, { timeout: 60000 });
}

async function shot(page, name) {
  if (shots) await page.screenshot({ path: `${shots}/studio-${name}.png` });
}

function noErrors(page) {
  check(consoleErrors.length === 0, `console errors: ${consoleErrors.join(" | ")}`);
  return page;
}

const origins = [];
function servePage() {
  // A page on another origin (for the cross-origin checks).
  return new Promise((resolve) => {
    const s = createServer((_, res) => {
      res.writeHead(200, { "content-type": "text/html" });
      res.end("<!doctype html><title>elsewhere</title><link rel=icon href='data:,'><p>another origin</p>");
    });
    s.listen(0, "127.0.0.1", () => {
      origins.push(s);
      resolve(s.address().port);
    });
  });
}

const browser = await chromium.launch({
  executablePath: args.chromium || process.env.CHOREO_CHROMIUM || "/usr/bin/chromium",
  args: [
    "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
    "--disable-quic", "--no-first-run", "--disable-background-networking",
    "--disable-component-update", "--disable-sync",
  ],
});
let failed = null;
try {
  const context = await browser.newContext({ viewport: { width: 1280, height: 760 }, acceptDownloads: true });
  const page = await context.newPage();
  page.on("console", (m) => {
    if (m.type() !== "error") return;
    if (allowResourceErrors && /Failed to load resource|CORS|Access-Control/i.test(m.text())) return;
    consoleErrors.push(m.text());
  });
  page.on("pageerror", (e) => consoleErrors.push(`page error: ${e.message}`));

  // ---- first paint, archive
  step = "archive";
  await page.goto(`${url}/#archive`);
  await ready(page);
  const paint = await page.evaluate(() => {
    const p = performance.getEntriesByType("paint").find((e) => e.name === "first-contentful-paint");
    const n = performance.getEntriesByType("navigation")[0];
    return { fcp: p ? p.startTime : null, load: n ? n.loadEventEnd : null };
  });
  results.first_contentful_paint_ms = paint.fcp;
  results.load_event_ms = paint.load;
  results.ready_ms = await page.evaluate(() => performance.now());
  const items = await page.locator("#motion-list li[data-id]").count();
  check(items >= 2, `the archive lists ${items} motions`);
  results.archive_motions = items;
  await page.locator("#motion-list li[data-id]").nth(1).click();
  await page.waitForFunction(() => window.__studio.playerTime > 0.3);
  await drawsAndMoves(page, "archive");
  // Playback rate: the stage's frames per second against the display's
  // (a bare requestAnimationFrame loop) over the same two seconds.
  const rate = await page.evaluate(async () => {
    let raf = 0;
    let go = true;
    const count = () => { raf++; if (go) requestAnimationFrame(count); };
    requestAnimationFrame(count);
    const f0 = window.__studio.framesDrawn;
    const t0 = performance.now();
    await new Promise((r) => setTimeout(r, 2000));
    go = false;
    const s = (performance.now() - t0) / 1000;
    return { stage: (window.__studio.framesDrawn - f0) / s, display: raf / s, joints: 24 };
  });
  results.playback_fps = rate.stage;
  results.display_fps = rate.display;
  check(rate.stage >= 0.9 * rate.display, `playback ${rate.stage.toFixed(1)} fps behind the display's ${rate.display.toFixed(1)}`);
  // Speed and scrub.
  await page.selectOption("#player .speed", "2");
  await page.locator("#player .scrub").fill("500");
  // Export: the glb download is a binary glTF.
  const [dl] = await Promise.all([page.waitForEvent("download"), page.click("#ex-glb")]);
  const glb = readFileSync(await dl.path());
  check(glb.subarray(0, 4).toString() === "glTF", "the glb export is not a binary glTF");
  const [dlb] = await Promise.all([page.waitForEvent("download"), page.click("#ex-bvh")]);
  check(readFileSync(await dlb.path()).toString().startsWith("HIERARCHY"), "the BVH export is not BVH");
  noErrors(page);
  await shot(page, "archive");

  // The studio's FK on stored motions, for the test to hold against the server's.
  if (args["fk-out"]) {
    const fk = await page.evaluate(async () => {
      const list = (await (await fetch("/v1/motions")).json()).motions;
      const out = [];
      for (const m of list.slice(0, 3)) {
        const r = await (await fetch(`/v1/motions/${m.id}`)).json();
        const frames = [0, Math.floor(r.motion.rotations.length / 2), r.motion.rotations.length - 1];
        out.push({ id: m.id, frames, positions: frames.map((f) => Array.from(window.__studio.fk(r.skeleton, r.motion.rotations[f], r.motion.translation[f]))) });
      }
      // A generated motion on the model's skeleton (as streamed frames are drawn).
      const model = await (await fetch("/v1/model")).json();
      const g = await (await fetch("/v1/generate", { method: "POST", headers: { "content-type": "application/json" },
        body: JSON.stringify({ frames: 10, sampling: { seed: 1 } }) })).json();
      const frames = [0, 9];
      out.push({ generated: g.output, skeleton: model.skeleton, frames,
        positions: frames.map((f) => Array.from(window.__studio.fk(model.skeleton, g.output.rotations[f], g.output.translation[f]))) });
      return out;
    });
    writeFileSync(args["fk-out"], JSON.stringify(fk));
  }

  // An upload the server cannot read: its error is shown, the page stays.
  step = "archive upload";
  await page.fill("#token", token);
  await page.click("#token-form button");
  await ready(page);
  allowResourceErrors = true;
  await page.setInputFiles("#up-file", { name: "broken.bvh", mimeType: "text/plain", buffer: Buffer.from("HIERARCHY\nROOT hips {\n") });
  await page.click("#up-go");
  await page.waitForSelector("#error:not([hidden])");
  const err = await page.textContent("#error");
  check(/motion\.file|broken\.bvh|invalid/i.test(err), `the upload error does not say what is wrong: ${err}`);
  results.upload_error_shown = err.trim();
  const still = await canvasStats(page);
  check(still.coloured > 200, "the canvas went blank after a failed upload");
  allowResourceErrors = false;
  await shot(page, "upload-error");

  // ---- search
  await goto(page, "#search");
  await page.fill("#q-start", "1");
  await page.click("#q-go");
  await page.waitForSelector("#hits li[data-i]");
  const hits = await page.locator("#hits li[data-i]").count();
  check(hits >= 1, "no hits");
  results.search_hits = hits;
  await page.waitForFunction(() => window.__studio.playerTime > 0.3);
  const rigs = await page.evaluate(() => document.querySelectorAll("#legend span").length);
  check(rigs === 2, `query and hit should play side by side (${rigs} shown)`);
  await page.locator("#hits li[data-i]").nth(Math.min(1, hits - 1)).click();
  await page.waitForTimeout(200);
  await drawsAndMoves(page, "search");
  noErrors(page);
  await shot(page, "search");

  // ---- generate
  await goto(page, "#generate");
  const firstLabel = await page.evaluate(() => {
    const s = document.querySelector("select[data-kind]");
    if (!s) return null;
    s.value = s.options[1].value;
    return `${s.dataset.kind}=${s.value}`;
  });
  results.generate_label = firstLabel;
  await page.fill("#g-seconds", "4");
  await page.fill("#g-seed", "7");
  await page.click("#g-go");
  await page.waitForFunction(() => window.__studio.streamed > 5);
  await drawsAndMoves(page, "generate_streaming");
  await page.waitForSelector("#g-status .ok", { timeout: 120000 });
  results.generate_first_frame_ms = await page.evaluate(() => window.__studio.firstFrameMs);
  results.generate_frames = await page.evaluate(() => window.__studio.streamed);
  check(results.generate_frames >= 79, `generated ${results.generate_frames} frames of 80`);
  // A labelled generation starts from a style exemplar, and the page says which.
  results.generate_exemplar = await page.evaluate(() => window.__studio.exemplar && window.__studio.exemplar.source);
  if (firstLabel) {
    check(results.generate_exemplar, "a labelled generation names no style exemplar");
    check((await page.textContent("#g-status")).includes("style exemplar"), "the status does not name the exemplar");
  }
  // The stream's start names the sampling that runs (defaults filled in), and the page shows it.
  results.generate_sampling = await page.evaluate(() => window.__studio.sampling);
  check(results.generate_sampling && Number.isInteger(results.generate_sampling.max_jump), "the stream's start names no sampling");
  check((await page.textContent("#g-status")).includes("max jump"), "the status does not show the sampling");
  check(!(await page.isDisabled("#g-save")), "the result cannot be downloaded");
  const [dlg] = await Promise.all([page.waitForEvent("download"), page.click("#g-save")]);
  const gen = JSON.parse(readFileSync(await dlg.path(), "utf8"));
  check(gen.rotations.length === results.generate_frames, "the downloaded motion lacks frames");
  // Steered toward the label (4 continuations every 20 frames, over the
  // same WebSocket), the root's path from the feet and the feet pinned:
  // as many frames come, a round at a time.
  if (firstLabel) {
    await page.check("#g-steer");
    await page.check("#g-feet");
    await page.check("#g-pin");
    await page.click("#g-go");
    await page.waitForSelector("#g-status .ok", { timeout: 120000 });
    results.generate_steered_frames = await page.evaluate(() => window.__studio.streamed);
    check(results.generate_steered_frames >= 79, `steered: ${results.generate_steered_frames} frames of 80`);
    await page.uncheck("#g-steer");
    await page.uncheck("#g-feet");
    await page.uncheck("#g-pin");
    // Holding the style (the bundled model has label postures): the
    // stream's start names posture 2 and max jump 12; free: posture 0.
    check(await page.$("#g-posture"), "the bundled model has postures, the page offers no posture choice");
    await page.selectOption("#g-posture", "hold");
    await page.click("#g-go");
    await page.waitForSelector("#g-status .ok", { timeout: 120000 });
    const held = await page.evaluate(() => window.__studio.sampling);
    check(held && held.posture === 2 && held.max_jump === 12, `held: the stream ran ${JSON.stringify(held)}`);
    results.generate_held_frames = await page.evaluate(() => window.__studio.streamed);
    check(results.generate_held_frames >= 79, `held: ${results.generate_held_frames} frames of 80`);
    await page.selectOption("#g-posture", "free");
    await page.click("#g-go");
    await page.waitForSelector("#g-status .ok", { timeout: 120000 });
    const free = await page.evaluate(() => window.__studio.sampling);
    check(free && free.posture === 0, `free: the stream ran ${JSON.stringify(free)}`);
    await page.selectOption("#g-posture", "");
    // Keeping the label (the frame model reads its last 20 frames): the
    // stream's start names context 20.
    check(await page.$("#g-keep"), "the bundled frame model's page offers no keep-the-label box");
    await page.check("#g-keep");
    await page.click("#g-go");
    await page.waitForSelector("#g-status .ok", { timeout: 120000 });
    const kept = await page.evaluate(() => window.__studio.sampling);
    check(kept && kept.context === 20, `keep: the stream ran ${JSON.stringify(kept)}`);
    results.generate_kept_frames = await page.evaluate(() => window.__studio.streamed);
    check(results.generate_kept_frames >= 79, `keep: ${results.generate_kept_frames} frames of 80`);
    await page.uncheck("#g-keep");
  }
  noErrors(page);
  await shot(page, "generate");

  // ---- keyframes
  await goto(page, "#keyframes");
  await page.fill("#k-count", "30");
  await page.click("#k-go");
  await page.waitForFunction(() => /MSE/.test(document.querySelector("#k-result").textContent), null, { timeout: 120000 });
  results.keyframes_result = (await page.textContent("#k-result")).trim();
  await page.waitForFunction(() => window.__studio.playerTime > 0.3);
  await drawsAndMoves(page, "keyframes");
  const plot = await canvasStats(page, "#plot");
  check(plot.coloured > 100, "the per-frame error plot is blank");
  noErrors(page);
  await shot(page, "keyframes");

  // ---- duet
  await goto(page, "#duet");
  await page.fill("#d-seconds", "3");
  await page.fill("#d-seed", "3");
  await page.click("#d-go");
  await page.waitForFunction(() => window.__studio.streamed > 10, null, { timeout: 60000 });
  await drawsAndMoves(page, "duet");
  await page.waitForSelector("#d-status .ok", { timeout: 60000 });
  results.duet_status = (await page.textContent("#d-status")).trim();
  noErrors(page);
  await shot(page, "duet");

  // ---- a page on another origin calls the API: allowed with CORS, refused without
  step = "cross-origin";
  allowResourceErrors = true;
  const other = corsPort ? null : await servePage();
  const allowed = corsPort;
  if (allowed) {
    // The allowed origin also serves three.js from web/node_modules, so a
    // page there can open the API's glb in three's own GLTFLoader.
    const threeDir = new URL("../../web/node_modules/three/", import.meta.url).pathname;
    const s = createServer((req, res) => {
      const path = decodeURIComponent(new URL(req.url, "http://x").pathname);
      if (path.startsWith("/three/") && path.endsWith(".js") && !path.includes("..")) {
        try {
          const body = readFileSync(threeDir + path.slice("/three/".length));
          res.writeHead(200, { "content-type": "text/javascript" });
          res.end(body);
        } catch (_) {
          res.writeHead(404);
          res.end();
        }
        return;
      }
      res.writeHead(200, { "content-type": "text/html" });
      res.end(`<!doctype html><title>studio elsewhere</title><link rel=icon href='data:,'>
        <script type="importmap">{"imports": {"three": "/three/build/three.module.js"}}</script><p>allowed origin</p>`);
    });
    await new Promise((r) => s.listen(allowed, "127.0.0.1", r));
    origins.push(s);
  }
  const refused = other || (await servePage());
  const call = async (port) => {
    const p = await context.newPage();
    await p.goto(`http://127.0.0.1:${port}/`);
    const r = await p.evaluate(async ([api, tok]) => {
      try {
        const a = await fetch(`${api}/v1/motions`, { headers: { Authorization: `Bearer ${tok}` } });
        return { ok: a.ok, status: a.status, motions: (await a.json()).motions.length };
      } catch (e) {
        return { ok: false, error: String(e) };
      }
    }, [url, token]);
    await p.close();
    return r;
  };
  if (allowed) {
    const r = await call(allowed);
    check(r.ok && r.motions > 0, `a page on the allowed origin could not call the API: ${JSON.stringify(r)}`);
    results.cors_allowed = r;
  }
  if (allowed) {
    // three.js's GLTFLoader opens the API's glb; its animation, played by
    // three's AnimationMixer, poses the joints (the test holds them against
    // the server's FK).
    step = "glTF in three.js";
    const p = await context.newPage();
    await p.goto(`http://127.0.0.1:${allowed}/`);
    const gltf = await p.evaluate(async ([api, tok]) => {
      const THREE = await import("three");
      const { GLTFLoader } = await import("/three/examples/jsm/loaders/GLTFLoader.js");
      const list = (await (await fetch(`${api}/v1/motions`, { headers: { Authorization: `Bearer ${tok}` } })).json()).motions;
      const out = [];
      for (const m of [list[0], list[list.length - 1]]) {
        const buf = await (await fetch(`${api}/v1/motions/${m.id}/glb`, { headers: { Authorization: `Bearer ${tok}` } })).arrayBuffer();
        const g = await new Promise((res, rej) => new GLTFLoader().parse(buf, "", res, rej));
        const nodes = await g.parser.getDependencies("node");
        const mixer = new THREE.AnimationMixer(g.scene);
        const action = mixer.clipAction(g.animations[0]);
        // Played once and held at the end: the last frame's time is the
        // clip's duration, where a looping action would wrap to frame 0.
        action.setLoop(THREE.LoopOnce);
        action.clampWhenFinished = true;
        action.play();
        let skinned = 0;
        g.scene.traverse((o) => { if (o.isSkinnedMesh) skinned++; });
        const frames = [0, Math.floor(m.frames / 2), m.frames - 1];
        const positions = frames.map((f) => {
          mixer.setTime(f / m.fps);
          g.scene.updateMatrixWorld(true);
          const v = new THREE.Vector3();
          return nodes.slice(0, m.joints).flatMap((n) => n.getWorldPosition(v).toArray());
        });
        out.push({ id: m.id, source: "glTF", frames, positions, skinned, duration: g.animations[0].duration, fps: m.fps, count: m.frames });
      }
      return out;
    }, [url, token]);
    await p.close();
    for (const g of gltf) {
      check(g.skinned === 1, `motion ${g.id}: ${g.skinned} skinned meshes`);
      check(Math.abs(g.duration - (g.count - 1) / g.fps) < 1e-3, `motion ${g.id}: animation lasts ${g.duration} s`);
    }
    results.gltf_loader = gltf.map((g) => ({ id: g.id, skinned: g.skinned, duration_s: g.duration }));
    if (args["gltf-out"]) writeFileSync(args["gltf-out"], JSON.stringify(gltf));
  }
  step = "cross-origin";
  const r2 = await call(refused);
  check(!r2.ok && r2.error, `a page on another origin read the API without CORS: ${JSON.stringify(r2)}`);
  results.cors_refused = r2;
} catch (e) {
  failed = e;
  // What the page showed when the check failed.
  try {
    const pages = browser.contexts().flatMap((c) => c.pages());
    if (pages.length) await pages[0].screenshot({ path: args["failure-shot"] || "studio-failure.png" });
  } catch (_) {}
} finally {
  await browser.close();
  for (const s of origins) s.close();
}
console.log(JSON.stringify(results, null, 1));
if (failed) {
  console.error(`studio check failed at ${failed.message}`);
  process.exit(1);
}
