// The 3D stage: one three.js scene with orbit controls, a floor, and any
// number of skeletons ("rigs") drawn as bones and joints. A Player moves
// every rig's clip on one clock, so a query and its hit, or an original and
// its rebuild, stay in step.
import {
  AmbientLight,
  BoxGeometry,
  Color,
  DirectionalLight,
  GridHelper,
  InstancedMesh,
  Matrix4,
  Mesh,
  MeshStandardMaterial,
  Object3D,
  PerspectiveCamera,
  Quaternion,
  Scene,
  SphereGeometry,
  Vector3,
  WebGLRenderer,
} from "three";
import { OrbitControls } from "three/examples/jsm/controls/OrbitControls.js";

const UP = new Vector3(0, 1, 0);

export class Stage {
  constructor(container) {
    this.container = container;
    this.renderer = new WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
    this.renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
    this.renderer.domElement.className = "stage-canvas";
    container.appendChild(this.renderer.domElement);
    this.scene = new Scene();
    this.scene.background = new Color(0x15171c);
    this.camera = new PerspectiveCamera(45, 1, 0.05, 200);
    this.camera.position.set(0, 1.6, 4.5);
    this.controls = new OrbitControls(this.camera, this.renderer.domElement);
    this.controls.target.set(0, 0.9, 0);
    this.controls.update();
    this.scene.add(new AmbientLight(0xffffff, 0.55));
    const sun = new DirectionalLight(0xffffff, 1.6);
    sun.position.set(3, 6, 4);
    this.scene.add(sun);
    const grid = new GridHelper(20, 40, 0x3a4050, 0x262a33);
    this.scene.add(grid);
    this.rigs = [];
    this.onFrame = [];
    this.framesDrawn = 0;
    this.resize();
    new ResizeObserver(() => this.resize()).observe(container);
    const loop = (now) => {
      for (const f of this.onFrame) f(now);
      this.renderer.render(this.scene, this.camera);
      this.framesDrawn++;
      requestAnimationFrame(loop);
    };
    requestAnimationFrame(loop);
  }

  resize() {
    const w = Math.max(this.container.clientWidth, 1);
    const h = Math.max(this.container.clientHeight, 1);
    this.renderer.setSize(w, h, false);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
  }

  addRig(skeleton, color, shift = [0, 0]) {
    const rig = new Rig(skeleton, color, shift);
    this.scene.add(rig.group);
    this.rigs.push(rig);
    return rig;
  }

  clear() {
    for (const r of this.rigs) {
      this.scene.remove(r.group);
      r.dispose();
    }
    this.rigs = [];
  }

  /** Point the camera at these positions (Float32Arrays of joints × 3). */
  frame(frames) {
    let min = [Infinity, Infinity, Infinity];
    let max = [-Infinity, -Infinity, -Infinity];
    for (const { pos, shift } of frames) {
      for (let i = 0; i < pos.length; i += 3) {
        const p = [pos[i] + shift[0], pos[i + 1], pos[i + 2] + shift[1]];
        for (let a = 0; a < 3; a++) {
          if (p[a] < min[a]) min[a] = p[a];
          if (p[a] > max[a]) max[a] = p[a];
        }
      }
    }
    if (!isFinite(min[0])) return;
    const c = new Vector3((min[0] + max[0]) / 2, (min[1] + max[1]) / 2, (min[2] + max[2]) / 2);
    const size = Math.max(max[0] - min[0], max[1] - min[1], max[2] - min[2], 1.8);
    this.controls.target.copy(c);
    this.camera.position.set(c.x + size * 0.35, c.y + size * 0.35, c.z + size * 1.6);
    this.controls.update();
  }
}

/** One skeleton: a box per bone, a sphere per joint, one InstancedMesh each. */
export class Rig {
  constructor(skeleton, color, shift) {
    this.skeleton = skeleton;
    // Added to x and z of every joint (side-by-side views).
    this.shift = shift;
    this.group = new Object3D();
    const j = skeleton.parents.length;
    this.bones = [];
    for (let k = 0; k < j; k++) if (skeleton.parents[k] !== null) this.bones.push(k);
    const mat = new MeshStandardMaterial({ color, roughness: 0.55, metalness: 0.1 });
    const jointMat = new MeshStandardMaterial({ color: 0xf2f2f2, roughness: 0.4 });
    this.boneMesh = new InstancedMesh(new BoxGeometry(1, 1, 1), mat, Math.max(this.bones.length, 1));
    this.jointMesh = new InstancedMesh(new SphereGeometry(1, 12, 8), jointMat, j);
    this.boneMesh.frustumCulled = false;
    this.jointMesh.frustumCulled = false;
    this.group.add(this.boneMesh, this.jointMesh);
    // Hidden until posed: unposed instances are unit boxes at the origin.
    this.group.visible = false;
    this.m = new Matrix4();
    this.q = new Quaternion();
    this.a = new Vector3();
    this.b = new Vector3();
    this.d = new Vector3();
    this.s = new Vector3();
  }

  /** Pose the rig from joints × 3 positions (metres). */
  setPose(pos) {
    const { m, q, a, b, d, s } = this;
    const [sx, sz] = this.shift;
    const j = this.skeleton.parents.length;
    for (let k = 0; k < j; k++) {
      a.set(pos[k * 3] + sx, pos[k * 3 + 1], pos[k * 3 + 2] + sz);
      s.set(0.028, 0.028, 0.028);
      m.compose(a, q.identity(), s);
      this.jointMesh.setMatrixAt(k, m);
    }
    this.bones.forEach((k, i) => {
      const p = this.skeleton.parents[k];
      a.set(pos[p * 3] + sx, pos[p * 3 + 1], pos[p * 3 + 2] + sz);
      b.set(pos[k * 3] + sx, pos[k * 3 + 1], pos[k * 3 + 2] + sz);
      d.subVectors(b, a);
      const len = d.length();
      if (len < 1e-6) {
        s.set(0, 0, 0);
        q.identity();
      } else {
        q.setFromUnitVectors(UP, d.multiplyScalar(1 / len));
        s.set(0.035, len, 0.035);
      }
      a.add(b).multiplyScalar(0.5);
      m.compose(a, q, s);
      this.boneMesh.setMatrixAt(i, m);
    });
    this.boneMesh.instanceMatrix.needsUpdate = true;
    this.jointMesh.instanceMatrix.needsUpdate = true;
    this.group.visible = true;
  }

  dispose() {
    this.boneMesh.geometry.dispose();
    this.jointMesh.geometry.dispose();
    this.boneMesh.material.dispose();
    this.jointMesh.material.dispose();
  }
}

/**
 * Plays clips on one clock. A clip is `{rig, fps, frames: [Float32Array],
 * start, length}`; `start`/`length` (frames) pick a segment, looped. The
 * transport (play, scrub, speed) lives in `controls`, a `.player` element.
 */
export class Player {
  constructor(stage, controls) {
    this.stage = stage;
    this.clips = [];
    this.t = 0;
    this.speed = 1;
    this.playing = false;
    this.last = null;
    this.live = false;
    this.el = controls;
    controls.innerHTML = `
      <button class="play" type="button" title="play / pause (space)">▶</button>
      <input class="scrub" type="range" min="0" max="1000" value="0" step="1" aria-label="time">
      <span class="clock">0.00 / 0.00 s</span>
      <label>speed <select class="speed">
        <option value="0.25">¼×</option><option value="0.5">½×</option>
        <option value="1" selected>1×</option><option value="2">2×</option>
      </select></label>`;
    this.button = controls.querySelector(".play");
    this.scrub = controls.querySelector(".scrub");
    this.clock = controls.querySelector(".clock");
    this.button.onclick = () => this.toggle();
    this.scrub.oninput = () => {
      this.t = (this.scrub.value / 1000) * this.duration();
      this.show();
    };
    controls.querySelector(".speed").onchange = (e) => (this.speed = Number(e.target.value));
    stage.onFrame.push((now) => this.tick(now));
  }

  duration() {
    let d = 0;
    for (const c of this.clips) d = Math.max(d, c.length / c.fps);
    return d;
  }

  setClips(clips, { play = true } = {}) {
    this.clips = clips;
    this.t = 0;
    this.last = null;
    this.playing = play;
    this.button.textContent = play ? "❚❚" : "▶";
    this.show();
  }

  toggle() {
    this.playing = !this.playing;
    this.last = null;
    this.button.textContent = this.playing ? "❚❚" : "▶";
  }

  tick(now) {
    if (this.playing && this.clips.length) {
      if (this.last !== null) {
        this.t += ((now - this.last) / 1000) * this.speed;
        const d = this.duration();
        // A live clip (still streaming) holds at its newest frame.
        if (this.live) this.t = Math.min(this.t, d);
        else if (d > 0) this.t %= d;
      }
      this.last = now;
      this.show();
    }
  }

  show() {
    const d = this.duration();
    for (const c of this.clips) {
      if (!c.length) continue;
      const i = Math.min(Math.floor(this.t * c.fps), c.length - 1);
      const f = c.frames[(c.start || 0) + (i % c.length)];
      if (f) c.rig.setPose(f);
    }
    this.scrub.value = d > 0 ? Math.round((this.t / d) * 1000) : 0;
    this.clock.textContent = `${this.t.toFixed(2)} / ${d.toFixed(2)} s`;
    window.__studio.playerTime = this.t;
  }
}
