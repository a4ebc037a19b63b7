// radslam web viewer: polls /state.json (at most 4 Hz, one request in flight), reloads the
// latest images when their sequence numbers change, plots the trajectory, and drives a free
// orbit camera that asks the renderer for views (GET /render). Vanilla JS, no network access.
'use strict';

const POLL_MS = 250;
const state = { last: null, seq: {}, free: null, rendering: false, pending: false };

function $(id) { return document.getElementById(id); }

// ---- images: one load in flight per image, only when its sequence number changed ----
const loading = {};
function refreshImage(name, seq) {
  if (!seq || state.seq[name] === seq || loading[name]) return;
  loading[name] = true;
  const img = new Image();
  img.onload = () => {
    loading[name] = false;
    state.seq[name] = seq;
    if (name === 'render') {
      if (!state.free) drawToCanvas($('render'), img);
    } else {
      $(name).src = img.src;
    }
  };
  img.onerror = () => { loading[name] = false; };
  img.src = '/image/' + name + '.jpg?seq=' + seq;
}

function drawToCanvas(canvas, img) {
  if (canvas.width !== img.naturalWidth || canvas.height !== img.naturalHeight) {
    canvas.width = img.naturalWidth;
    canvas.height = img.naturalHeight;
  }
  canvas.getContext('2d').drawImage(img, 0, 0);
}

// ---- trajectory plot: top view (x right, z up on screen) ----
// Moving objects (OBJECTS): one track each, labelled with id and joint.
const kObjectColours = ['#6e6', '#e6e', '#ee6', '#6ee', '#f88'];

function drawTrajectory(est, gt, objects) {
  const c = $('trajectory');
  const g = c.getContext('2d');
  g.fillStyle = '#000';
  g.fillRect(0, 0, c.width, c.height);
  const tracks = (objects || []).filter((o) => o.track.length > 0);
  const all = tracks.reduce((pts, o) => pts.concat(o.track), est.concat(gt));
  if (all.length === 0) {
    g.fillStyle = '#888';
    g.fillText('no poses yet', 10, 20);
    return;
  }
  let x0 = Infinity, x1 = -Infinity, z0 = Infinity, z1 = -Infinity;
  for (const [x, z] of all) {
    x0 = Math.min(x0, x); x1 = Math.max(x1, x); z0 = Math.min(z0, z); z1 = Math.max(z1, z);
  }
  const span = Math.max(x1 - x0, z1 - z0, 1e-3);
  const s = 0.9 * Math.min(c.width, c.height) / span;
  const cx = (x0 + x1) / 2, cz = (z0 + z1) / 2;
  const px = (x) => c.width / 2 + (x - cx) * s;
  const pz = (z) => c.height / 2 - (z - cz) * s;
  const line = (pts, colour) => {
    if (pts.length === 0) return;
    g.strokeStyle = colour;
    g.lineWidth = 2;
    g.beginPath();
    pts.forEach(([x, z], i) => (i ? g.lineTo(px(x), pz(z)) : g.moveTo(px(x), pz(z))));
    g.stroke();
    const [lx, lz] = pts[pts.length - 1];
    g.fillStyle = colour;
    g.beginPath();
    g.arc(px(lx), pz(lz), 4, 0, 2 * Math.PI);
    g.fill();
  };
  line(gt, '#fb4');
  line(est, '#4af');
  tracks.forEach((o, i) => {
    const colour = kObjectColours[i % kObjectColours.length];
    line(o.track, colour);
    const [lx, lz] = o.track[o.track.length - 1];
    g.fillText('object ' + o.id + ' (' + o.joint + ')', px(lx) + 6, pz(lz) - 6);
  });
  g.fillStyle = '#888';
  g.fillText('scale: ' + span.toFixed(2) + ' m across', 8, c.height - 8);
}

function esc(s) {
  return String(s).replace(/[&<>"]/g, (ch) => ({ '&': '&amp;', '<': '&lt;', '>': '&gt;', '"': '&quot;' })[ch]);
}

function drawStatus(list) {
  const rows = list.map((p) =>
    '<tr><td>' + esc(p.process) + '</td><td class="state-' + esc(p.state) + '">' + esc(p.state) +
    '</td><td>' + (p.fps === null ? '-' : p.fps.toFixed(1)) + '</td><td>' + p.items +
    '</td><td>' + p.frame + '</td><td>' + p.queue + '</td><td>' +
    (p.rss_mb === null ? '-' : p.rss_mb.toFixed(0)) + '</td><td class="error" title="' +
    esc(p.last_error) + '">' + esc(p.last_error) + '</td></tr>');
  $('status').tBodies[0].innerHTML = rows.join('');
}

function update(s) {
  state.last = s;
  $('summary').textContent = 'field v' + s.field.version + ' (' + s.field.blocks + ' blocks) | ' +
      s.keyframes + ' keyframes | frame ' + s.frame_index + (s.run_ended ? ' | run ended' : '');
  $('frame-label').textContent = s.frame_index >= 0 ? '#' + s.frame_index : '';
  for (const name of ['camera', 'render', 'depth', 'sigma']) refreshImage(name, s.images[name]);
  drawTrajectory(s.trajectory, s.ground_truth, s.objects);
  drawStatus(s.status);
}

function poll() {
  fetch('/state.json', { cache: 'no-store' })
      .then((r) => r.json())
      .then((s) => {
        $('connection').textContent = 'live';
        $('connection').className = 'ok';
        update(s);
      })
      .catch(() => {
        $('connection').textContent = 'offline';
        $('connection').className = 'bad';
      })
      .finally(() => setTimeout(poll, POLL_MS));
}

// ---- free camera: orbit (yaw, pitch, radius) around a target; OpenCV camera (y down) ----
function norm(v) { const n = Math.hypot(v[0], v[1], v[2]) || 1; return [v[0] / n, v[1] / n, v[2] / n]; }
function cross(a, b) { return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]; }

function quatFromColumns(x, y, z) {
  // Rotation matrix with columns x, y, z -> quaternion (x, y, z, w).
  const m00 = x[0], m01 = y[0], m02 = z[0], m10 = x[1], m11 = y[1], m12 = z[1];
  const m20 = x[2], m21 = y[2], m22 = z[2];
  const tr = m00 + m11 + m22;
  let qw, qx, qy, qz;
  if (tr > 0) {
    const s = Math.sqrt(tr + 1) * 2;
    qw = 0.25 * s; qx = (m21 - m12) / s; qy = (m02 - m20) / s; qz = (m10 - m01) / s;
  } else if (m00 > m11 && m00 > m22) {
    const s = Math.sqrt(1 + m00 - m11 - m22) * 2;
    qw = (m21 - m12) / s; qx = 0.25 * s; qy = (m01 + m10) / s; qz = (m02 + m20) / s;
  } else if (m11 > m22) {
    const s = Math.sqrt(1 + m11 - m00 - m22) * 2;
    qw = (m02 - m20) / s; qx = (m01 + m10) / s; qy = 0.25 * s; qz = (m12 + m21) / s;
  } else {
    const s = Math.sqrt(1 + m22 - m00 - m11) * 2;
    qw = (m10 - m01) / s; qx = (m02 + m20) / s; qy = (m12 + m21) / s; qz = 0.25 * s;
  }
  return [qx, qy, qz, qw];
}

function startFree() {
  const s = state.last;
  if (!s || !s.pose) return null;
  const p = s.pose.t;
  let c;
  if (s.field.bounds) {
    const b = s.field.bounds;
    c = [(b[0] + b[3]) / 2, (b[1] + b[4]) / 2, (b[2] + b[5]) / 2];
  } else {
    c = [p[0], p[1], p[2] + 1];
  }
  const v = [p[0] - c[0], p[1] - c[1], p[2] - c[2]];
  const r = Math.max(Math.hypot(v[0], v[1], v[2]), 0.1);
  return { target: c, radius: r, yaw: Math.atan2(v[0], v[2]), pitch: Math.asin(-v[1] / r) };
}

function freePose(f) {
  const cp = Math.cos(f.pitch);
  const p = [f.target[0] + f.radius * cp * Math.sin(f.yaw), f.target[1] - f.radius * Math.sin(f.pitch),
    f.target[2] + f.radius * cp * Math.cos(f.yaw)];
  const z = norm([f.target[0] - p[0], f.target[1] - p[1], f.target[2] - p[2]]);
  const x = norm(cross([0, 1, 0], z));
  const y = cross(z, x);
  return p.concat(quatFromColumns(x, y, z));
}

function requestFreeView() {
  if (!state.free) return;
  if (state.rendering) { state.pending = true; return; }  // one request in flight
  state.rendering = true;
  const canvas = $('render');
  const cam = state.last && state.last.camera;
  const w = 320, h = cam && cam.width > 0 ? Math.round(320 * cam.height / cam.width) : 240;
  const fx = cam && cam.width > 0 ? cam.fx * w / cam.width : 0.8 * w;
  const pose = freePose(state.free).map((v) => v.toFixed(5)).join(',');
  const img = new Image();
  const done = () => {
    state.rendering = false;
    if (state.pending) { state.pending = false; requestFreeView(); }
  };
  img.onload = () => { if (state.free) drawToCanvas(canvas, img); done(); };
  img.onerror = done;
  img.src = '/render?pose=' + pose + '&w=' + w + '&h=' + h + '&fx=' + fx.toFixed(3) + '&kind=color';
}

function setupFreeCamera() {
  const canvas = $('render');
  let drag = null;
  const enter = () => {
    if (!state.free) state.free = startFree();
    $('view-mode').textContent = state.free ? 'free camera' : 'follow';
    return state.free;
  };
  canvas.addEventListener('mousedown', (e) => { if (enter()) drag = [e.clientX, e.clientY]; });
  window.addEventListener('mouseup', () => { drag = null; });
  window.addEventListener('mousemove', (e) => {
    if (!drag || !state.free) return;
    state.free.yaw -= (e.clientX - drag[0]) * 0.01;
    state.free.pitch = Math.max(-1.5, Math.min(1.5, state.free.pitch + (e.clientY - drag[1]) * 0.01));
    drag = [e.clientX, e.clientY];
    requestFreeView();
  });
  canvas.addEventListener('wheel', (e) => {
    e.preventDefault();
    if (!enter()) return;
    state.free.radius = Math.max(0.05, state.free.radius * Math.exp(e.deltaY * 0.001));
    requestFreeView();
  }, { passive: false });
  $('follow').addEventListener('click', () => {
    state.free = null;
    state.seq.render = null;  // redraw the follow view
    $('view-mode').textContent = 'follow';
  });
}

setupFreeCamera();
poll();
