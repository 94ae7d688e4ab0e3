/*
 * odofuse teach: the four panels (controls, computation through model.js, drawing on canvas).
 * window.odofuseTeach.state() returns every number the page shows, for tests and students.
 */
(function () {
  "use strict";
  const M = window.odofuseModel;
  const CFG = JSON.parse(document.getElementById("odofuse-config").textContent);
  const params = { growth: {}, umbmark: {}, drives: {}, fusion: {} };
  const results = { growth: null, umbmark: null, drives: null, fusion: null };
  const timing = {}; // per panel: <panel>_ms (compute + draw), <panel>_compute_ms, <panel>_draw_ms
  const CHI2_2_95 = -2 * Math.log(0.05); // 95 % quantile of chi-square, 2 dof

  // ------------------------------------------------------------------------- controls
  function fmt(v, digits) {
    if (v === null || v === undefined || Number.isNaN(v)) return "—";
    if (typeof v !== "number") return String(v);
    const a = Math.abs(v);
    if (a !== 0 && (a < 1e-3 || a >= 1e5)) return v.toExponential(digits ?? 3);
    return v.toFixed(digits ?? 4);
  }

  function addSlider(panel, key, spec, onChange) {
    const box = document.getElementById(panel + "-controls");
    const label = document.createElement("label");
    const id = panel + "-" + key;
    const out = document.createElement("span");
    out.className = "value";
    out.id = id + "-value";
    label.htmlFor = id;
    label.textContent = spec.label + (spec.unit ? " [" + spec.unit + "]" : "");
    label.appendChild(out);
    const input = document.createElement("input");
    input.type = "range";
    input.id = id;
    input.dataset.key = key;
    input.dataset.log = spec.log ? "1" : "0";
    if (spec.log) {
      input.min = Math.log10(spec.min);
      input.max = Math.log10(spec.max);
      input.step = spec.step;
      input.value = Math.log10(spec.value);
    } else {
      input.min = spec.min;
      input.max = spec.max;
      input.step = spec.step;
      input.value = spec.value;
    }
    const read = () => {
      const raw = Number(input.value);
      const v = spec.log ? Math.pow(10, raw) : raw;
      params[panel][key] = v;
      const text = spec.log ? v.toExponential(2) : fmt(v, spec.step >= 1 ? 0 : undefined);
      out.textContent = text + (spec.unit ? " " + spec.unit : "");
    };
    read();
    input.addEventListener("input", () => { read(); onChange(); });
    box.appendChild(label);
    box.appendChild(input);
  }

  function addSelect(panel, key, spec, onChange, title) {
    const box = document.getElementById(panel + "-controls");
    const label = document.createElement("label");
    label.textContent = title;
    const sel = document.createElement("select");
    sel.id = panel + "-" + key;
    for (const o of spec.options) {
      const opt = document.createElement("option");
      opt.value = o;
      opt.textContent = o.replace("_", "-");
      sel.appendChild(opt);
    }
    sel.value = spec.value;
    params[panel][key] = spec.value;
    sel.addEventListener("change", () => { params[panel][key] = sel.value; onChange(); });
    label.appendChild(document.createElement("br"));
    label.appendChild(sel);
    box.appendChild(label);
  }

  function addCheckbox(panel, key, value, onChange, title) {
    const box = document.getElementById(panel + "-controls");
    const label = document.createElement("label");
    const cb = document.createElement("input");
    cb.type = "checkbox";
    cb.id = panel + "-" + key;
    cb.checked = value;
    params[panel][key] = value;
    cb.addEventListener("change", () => { params[panel][key] = cb.checked; onChange(); });
    label.appendChild(cb);
    label.appendChild(document.createTextNode(" " + title));
    box.appendChild(label);
  }

  function table(id, rows) {
    const el = document.getElementById(id);
    el.innerHTML = "";
    const t = document.createElement("table");
    for (const [k, v, cls] of rows) {
      const tr = document.createElement("tr");
      const a = document.createElement("td");
      a.textContent = k;
      const b = document.createElement("td");
      b.textContent = v;
      if (cls) b.className = cls;
      tr.appendChild(a);
      tr.appendChild(b);
      t.appendChild(tr);
    }
    el.appendChild(t);
  }

  // ------------------------------------------------------------------------- drawing
  /** An equal-aspect world-to-pixel view of the box [x0, x1] x [y0, y1] (m). */
  function view(canvas, box, margin) {
    const m = margin ?? 40;
    let [x0, x1, y0, y1] = box;
    if (!(x1 > x0)) { x0 -= 0.5; x1 += 0.5; }
    if (!(y1 > y0)) { y0 -= 0.5; y1 += 0.5; }
    const w = canvas.width - 2 * m, h = canvas.height - 2 * m;
    const s = Math.min(w / (x1 - x0), h / (y1 - y0));
    const cx = 0.5 * (x0 + x1), cy = 0.5 * (y0 + y1);
    return {
      s,
      px: (x) => canvas.width / 2 + (x - cx) * s,
      py: (y) => canvas.height / 2 - (y - cy) * s,
      box: [cx - canvas.width / 2 / s, cx + canvas.width / 2 / s, cy - canvas.height / 2 / s, cy + canvas.height / 2 / s],
    };
  }
  function bounds(points) {
    let x0 = Infinity, x1 = -Infinity, y0 = Infinity, y1 = -Infinity;
    for (const p of points) {
      if (!Number.isFinite(p[0]) || !Number.isFinite(p[1])) continue;
      x0 = Math.min(x0, p[0]); x1 = Math.max(x1, p[0]);
      y0 = Math.min(y0, p[1]); y1 = Math.max(y1, p[1]);
    }
    return [x0, x1, y0, y1];
  }
  function niceStep(span) {
    const raw = span / 6, p = Math.pow(10, Math.floor(Math.log10(raw)));
    for (const f of [1, 2, 5, 10]) if (f * p >= raw) return f * p;
    return 10 * p;
  }
  function grid(ctx, v, unit) {
    const [x0, x1, y0, y1] = v.box;
    const st = niceStep(Math.max(x1 - x0, y1 - y0));
    ctx.save();
    ctx.strokeStyle = "#e4e4e4";
    ctx.fillStyle = "#777";
    ctx.font = "11px sans-serif";
    ctx.lineWidth = 1;
    for (let x = Math.ceil(x0 / st) * st; x <= x1; x += st) {
      ctx.beginPath(); ctx.moveTo(v.px(x), 0); ctx.lineTo(v.px(x), ctx.canvas.height); ctx.stroke();
      ctx.fillText(+x.toPrecision(6) + " " + unit, v.px(x) + 2, ctx.canvas.height - 4);
    }
    for (let y = Math.ceil(y0 / st) * st; y <= y1; y += st) {
      ctx.beginPath(); ctx.moveTo(0, v.py(y)); ctx.lineTo(ctx.canvas.width, v.py(y)); ctx.stroke();
      ctx.fillText(+y.toPrecision(6) + " " + unit, 2, v.py(y) - 2);
    }
    ctx.restore();
  }
  function polyline(ctx, v, pts, color, width, dash) {
    ctx.save();
    ctx.strokeStyle = color;
    ctx.lineWidth = width ?? 1.5;
    ctx.setLineDash(dash ?? []);
    ctx.beginPath();
    pts.forEach((p, i) => (i ? ctx.lineTo(v.px(p[0]), v.py(p[1])) : ctx.moveTo(v.px(p[0]), v.py(p[1]))));
    ctx.stroke();
    ctx.restore();
  }
  function dots(ctx, v, pts, color, r) {
    ctx.save();
    ctx.fillStyle = color;
    for (const p of pts) ctx.fillRect(v.px(p[0]) - r, v.py(p[1]) - r, 2 * r, 2 * r);
    ctx.restore();
  }
  function legend(ctx, items, x, y) {
    ctx.save();
    ctx.font = "12px sans-serif";
    const wmax = Math.max(...items.map(([, text]) => ctx.measureText(text).width));
    ctx.fillStyle = "rgba(255, 255, 255, 0.85)";
    ctx.fillRect(x - 4, y - 9, wmax + 38, 16 * items.length + 2);
    items.forEach(([color, text, dash], i) => {
      ctx.strokeStyle = color;
      ctx.setLineDash(dash ?? []);
      ctx.lineWidth = 2;
      ctx.beginPath(); ctx.moveTo(x, y + 16 * i); ctx.lineTo(x + 22, y + 16 * i); ctx.stroke();
      ctx.fillStyle = "#222";
      ctx.fillText(text, x + 28, y + 4 + 16 * i);
    });
    ctx.restore();
  }
  function title(ctx, text, x, y) {
    ctx.save();
    ctx.font = "bold 13px sans-serif";
    ctx.fillStyle = "#222";
    ctx.fillText(text, x ?? 8, y ?? 16);
    ctx.restore();
  }
  function clear(canvas) {
    const ctx = canvas.getContext("2d");
    ctx.fillStyle = "#fff";
    ctx.fillRect(0, 0, canvas.width, canvas.height);
    return ctx;
  }
  const COLORS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#9467bd", "#d62728", "#8c564b"];

  // ------------------------------------------------------------------ panel 1: error growth
  function growthTwists(p) {
    const G = CFG.growth, s = p.step;
    if (p.path === "straight") return M.straight(G.straight_length, s, 1.0);
    if (p.path === "circle") return M.arc(2 * Math.PI, G.circle_radius, s, 1.0);
    if (p.path === "square") return M.squareTwists(G.square_side, "ccw", s, G.turn_per_step_per_m * s, 1.0);
    return M.figureEightTwists(G.eight_radius, s, 1.0);
  }
  function growthSetup(p) {
    const geom = { wheel_radius: p.wheel_radius, track_width: p.track_width };
    const twists = growthTwists(p);
    const U = twists.map((tw) => M.diffInverse(geom, tw));
    const model = { geom, k: [p.k_l, p.k_r], integrator: p.integrator };
    const trueGeom = M.trueGeometry(geom, p.E_d, p.E_b);
    return { geom, twists, U, model, trueGeom };
  }

  /** The Monte Carlo's standard normal draws, run r's in draws(r) (left, right per step):
   * the same seeded sequence on every update, kept while the number of runs and steps stay
   * (a move of k, E_d, E_b, r or b then only rescales them; up to 4e6 draws, 32 MB). */
  let drawCache = { key: null, z: null };
  const MAX_CACHED_DRAWS = 4e6;
  function standardNormals(seed, runs, perRun) {
    const key = `${seed}:${runs}:${perRun}`;
    if (drawCache.key !== key && runs * perRun <= MAX_CACHED_DRAWS) {
      const rng = M.makeRng(seed), z = new Float64Array(runs * perRun);
      for (let i = 0; i < z.length; i++) z[i] = rng.normal();
      drawCache = { key, z };
    }
    if (drawCache.key === key) return (r) => drawCache.z.subarray(r * perRun, (r + 1) * perRun);
    const rng = M.makeRng(seed), buf = new Float64Array(perRun); // too many to keep: stream
    return () => { for (let i = 0; i < perRun; i++) buf[i] = rng.normal(); return buf; };
  }

  function computeGrowth() {
    const p = { ...params.growth, path: params.growth.path, integrator: params.growth.integrator };
    const { geom, twists, U, model, trueGeom } = growthSetup(p);
    const Z3 = [[0, 0, 0], [0, 0, 0], [0, 0, 0]];
    const dr = M.deadReckon(model, [0, 0, 0], Z3, U);
    const truth = M.truePath(trueGeom, U, [0, 0, 0]);
    const N = U.length, C = CFG.growth.checkpoints;
    const idx = [];
    for (let j = 1; j <= C; j++) idx.push(Math.max(1, Math.round((N * j) / C)));
    const at = new Int32Array(N + 1).fill(-1);
    idx.forEach((k, j) => { at[k] = j; });
    // Monte Carlo: the true robot, noisy wheels through the true geometry (simulate.simulate)
    const n = Math.round(p.samples);
    const draws = standardNormals(CFG.growth.seed, n, 2 * N);
    const F = M.diffMatrix(trueGeom);
    const rl = geom.wheel_radius, rr = geom.wheel_radius;
    const cloud = idx.map(() => []);
    // per-step noise standard deviations of the wheel angles: sqrt(k |u r|) / r
    const sdl = U.map((u) => Math.sqrt(p.k_l * Math.abs(u[0] * rl)) / rl);
    const sdr = U.map((u) => Math.sqrt(p.k_r * Math.abs(u[1] * rr)) / rr);
    const [F00, F01, F10, F11] = [F[0][0], F[0][1], F[1][0], F[1][1]];
    for (let r = 0; r < n; r++) {
      const z = draws(r);
      // the exact step (se2.exp) in half-angle form; the heading's cos and sin are carried
      // by rotation (cos w = 1 - 2 sin^2(w/2), sin w = 2 sin(w/2) cos(w/2))
      let x = 0, y = 0, h = 0, c = 1, s = 0;
      for (let k = 0; k < N; k++) {
        const ul = U[k][0] + z[2 * k] * sdl[k];
        const ur = U[k][1] + z[2 * k + 1] * sdr[k];
        const w = F00 * ul + F01 * ur, vx = F10 * ul + F11 * ur;
        const half = 0.5 * w, sh = Math.sin(half), ch = Math.cos(half);
        const sinc = w === 0 ? 1 : sh / half;
        const dx = sinc * ch * vx, dy = sinc * sh * vx;
        x += c * dx - s * dy;
        y += s * dx + c * dy;
        h += w;
        const cw = 1 - 2 * sh * sh, sw = 2 * sh * ch;
        const cn = c * cw - s * sw;
        s = s * cw + c * sw;
        c = cn;
        const j = at[k + 1];
        if (j >= 0) cloud[j].push([x, y, M.wrap(h)]);
      }
    }
    const bnds = M.neesBounds(n, 3, 0.95);
    const checkpoints = idx.map((k, j) => {
      const est = dr.poses[k], P = dr.covs[k];
      const pts = cloud[j];
      let sum = 0, inside = 0, mx = 0, my = 0, mt = 0;
      const Pxy = [[P[0][0], P[0][1]], [P[1][0], P[1][1]]];
      const Pi = M.inv(P), Pxyi = M.inv(Pxy);
      for (const q of pts) {
        const e = [q[0] - est[0], q[1] - est[1], M.wrap(q[2] - est[2])];
        let s3 = 0;
        for (let a = 0; a < 3; a++) for (let b = 0; b < 3; b++) s3 += e[a] * Pi[a][b] * e[b];
        sum += s3;
        const m2 = e[0] * (Pxyi[0][0] * e[0] + Pxyi[0][1] * e[1]) + e[1] * (Pxyi[1][0] * e[0] + Pxyi[1][1] * e[1]);
        if (m2 <= CHI2_2_95) inside++;
        mx += e[0]; my += e[1]; mt += e[2];
      }
      const mean = [mx / pts.length, my / pts.length, mt / pts.length];
      const cov = [[0, 0, 0], [0, 0, 0], [0, 0, 0]];
      for (const q of pts) {
        const e = [q[0] - est[0] - mean[0], q[1] - est[1] - mean[1], M.wrap(q[2] - est[2]) - mean[2]];
        for (let a = 0; a < 3; a++) for (let b = 0; b < 3; b++) cov[a][b] += (e[a] * e[b]) / (pts.length - 1);
      }
      let dist = 0;
      for (let i = 0; i < k; i++) dist += Math.abs(twists[i][1]);
      return {
        index: k, distance_m: dist, pose: est, cov: P, truth_noise_free: truth[k],
        nees: sum / pts.length, inside_95: inside / pts.length,
        mc_mean_error: mean, mc_cov_error: cov,
      };
    });
    const last = checkpoints[checkpoints.length - 1];
    results.growth = {
      params: p, n_steps: N, twists, inputs: U, true_geometry: trueGeom,
      final_pose: dr.poses[N], final_cov: dr.covs[N], truth_noise_free_final: truth[N],
      checkpoints, samples: n, nees_bounds_95: bnds,
      consistent_end: last.nees >= bnds[0] && last.nees <= bnds[1],
      _draw: { est: dr.poses, truth, cloud },
    };
  }

  function drawGrowth() {
    const R = results.growth, canvas = document.getElementById("growth-canvas");
    const ctx = clear(canvas);
    const pts = [...R._draw.est, ...R._draw.truth];
    const ells = R.checkpoints.map((c) => M.ellipse(c.pose, [[c.cov[0][0], c.cov[0][1]], [c.cov[1][0], c.cov[1][1]]], 0.95, 72));
    for (const c of R._draw.cloud) pts.push(...c);
    for (const e of ells) pts.push(...e);
    const v = view(canvas, bounds(pts));
    grid(ctx, v, "m");
    R._draw.cloud.forEach((c, j) => dots(ctx, v, c, COLORS[j % COLORS.length] + "66", 1.2));
    polyline(ctx, v, R._draw.truth, "#888", 1.5, [6, 4]);
    polyline(ctx, v, R._draw.est, "#000", 1.5);
    ells.forEach((e, j) => polyline(ctx, v, e, COLORS[j % COLORS.length], 2.2));
    title(ctx, `Error growth, ${R.params.path.replace("_", "-")}, ${R.params.integrator}, ${R.samples} runs, Δs = ${fmt(R.params.step, 3)} m`);
    legend(ctx, [["#000", "odometry (nominal geometry, chosen integrator)"], ["#888", "true robot without noise (E_d, E_b, exact)", [6, 4]],
      [COLORS[0], "95 % ellipses (linearised) and Monte Carlo at checkpoints"]], 12, 36);
    // NEES along the path
    const c2 = document.getElementById("growth-nees");
    const ctx2 = clear(c2);
    const xs = R.checkpoints.map((c) => c.distance_m), ys = R.checkpoints.map((c) => c.nees);
    const [lo, hi] = R.nees_bounds_95;
    const yTop = Math.log10(Math.max(30, ...ys.filter(Number.isFinite)) * 1.5), yBot = Math.log10(Math.min(1, lo) / 1.5);
    const X = (d) => 60 + (d / Math.max(...xs)) * (c2.width - 90);
    const Y = (n) => c2.height - 25 - ((Math.log10(n) - yBot) / (yTop - yBot)) * (c2.height - 45);
    ctx2.fillStyle = "#2ca02c33";
    ctx2.fillRect(60, Y(hi), c2.width - 90, Y(lo) - Y(hi));
    ctx2.strokeStyle = "#2ca02c";
    ctx2.setLineDash([4, 3]);
    ctx2.beginPath(); ctx2.moveTo(60, Y(3)); ctx2.lineTo(c2.width - 30, Y(3)); ctx2.stroke();
    ctx2.setLineDash([]);
    ctx2.strokeStyle = "#9467bd";
    ctx2.lineWidth = 2;
    ctx2.beginPath();
    xs.forEach((d, i) => (i ? ctx2.lineTo(X(d), Y(ys[i])) : ctx2.moveTo(X(d), Y(ys[i]))));
    ctx2.stroke();
    ctx2.fillStyle = "#222";
    ctx2.font = "11px sans-serif";
    xs.forEach((d, i) => { ctx2.fillRect(X(d) - 3, Y(ys[i]) - 3, 6, 6); ctx2.fillText(fmt(ys[i], 2), X(d) + 5, Y(ys[i]) - 5); ctx2.fillText(fmt(d, 2) + " m", X(d) - 14, c2.height - 8); });
    for (const n of [1, 3, 10, 100, 1000]) if (Math.log10(n) > yBot && Math.log10(n) < yTop) ctx2.fillText(String(n), 30, Y(n) + 4);
    title(ctx2, "mean NEES (3 dof) against distance travelled; green: 95 % bounds for the cloud size, dashed: 3");
    const P = R.final_cov, e = R.final_pose, last = R.checkpoints[R.checkpoints.length - 1];
    table("growth-numbers", [
      ["steps", String(R.n_steps)],
      ["odometry end x, y", `${fmt(e[0])} m, ${fmt(e[1])} m`],
      ["odometry end θ", `${fmt(e[2])} rad`],
      ["true (no noise) end x, y", `${fmt(R.truth_noise_free_final[0])} m, ${fmt(R.truth_noise_free_final[1])} m`],
      ["σx, σy (linearised)", `${fmt(Math.sqrt(P[0][0]))} m, ${fmt(Math.sqrt(P[1][1]))} m`],
      ["σθ (linearised)", `${fmt(Math.sqrt(P[2][2]))} rad`],
      ["NEES at end", fmt(last.nees, 3), R.consistent_end ? "good" : "bad"],
      ["95 % bounds", `[${fmt(R.nees_bounds_95[0], 3)}, ${fmt(R.nees_bounds_95[1], 3)}]`],
      ["verdict", R.consistent_end ? "ellipse describes the cloud" : "cloud and ellipse part", R.consistent_end ? "good" : "bad"],
      ["inside 95 % ellipse", `${fmt(100 * last.inside_95, 1)} %`],
      ["update time", `${fmt(timing.growth_ms, 1)} ms`],
    ]);
  }

  // ------------------------------------------------------------------ panel 2: UMBmark
  function computeUmbmark() {
    const p = { ...params.umbmark }, C = CFG.umbmark;
    const geom = { ...C.geometry };
    const trueGeom = M.trueGeometry(geom, p.E_d, p.E_b);
    const rng = M.makeRng(C.seed);
    const runs = Math.round(p.runs), k = [p.k, p.k];
    const Z3 = [[0, 0, 0], [0, 0, 0], [0, 0, 0]];
    function measure(nominal) {
      const out = { det: {}, errors: {}, paths: {} };
      for (const dir of ["cw", "ccw"]) {
        const tw = M.squareTwists(p.side, dir, C.speed, C.turn_rate, C.dt);
        const U = tw.map((t) => M.diffInverse(nominal, t));
        const model = { geom: nominal, k: [0, 0], integrator: "exact" };
        const odo = M.deadReckon(model, [0, 0, 0], Z3, U).poses;
        const det = M.truePath(trueGeom, U, [0, 0, 0]);
        out.det[dir] = M.returnError(det[det.length - 1], odo[odo.length - 1]);
        out.errors[dir] = [];
        for (let r = 0; r < runs; r++) {
          const tr = M.truePath(trueGeom, M.noisyInputs(nominal, k, U, rng), [0, 0, 0]);
          out.errors[dir].push(M.returnError(tr[tr.length - 1], odo[odo.length - 1]));
          if (r === 0) out.paths[dir] = tr.filter((_, i) => i % 4 === 0 || i === tr.length - 1);
        }
      }
      return out;
    }
    const before = measure(geom);
    const est = M.umbmarkEstimate(before.errors.cw, before.errors.ccw, p.side, geom.track_width, p.method);
    const estDet = M.umbmarkEstimate([before.det.cw], [before.det.ccw], p.side, geom.track_width, p.method);
    const fixed = M.correctedGeometry(geom, est.E_d, est.E_b);
    const after = measure(fixed);
    results.umbmark = {
      params: p, nominal_geometry: geom, true_geometry: trueGeom,
      noise_free_cw: before.det.cw, noise_free_ccw: before.det.ccw,
      errors_cw: before.errors.cw, errors_ccw: before.errors.ccw,
      estimate: est, estimate_noise_free: estDet, corrected_geometry: fixed,
      after_noise_free_cw: after.det.cw, after_noise_free_ccw: after.det.ccw,
      errors_after_cw: after.errors.cw, errors_after_ccw: after.errors.ccw,
      e_max_before: M.systematicReturnError(before.errors.cw, before.errors.ccw),
      e_max_after: M.systematicReturnError(after.errors.cw, after.errors.ccw),
      _draw: { before: before.paths, after: after.paths },
    };
  }

  function drawUmbmark() {
    const R = results.umbmark, canvas = document.getElementById("umbmark-canvas");
    const ctx = clear(canvas);
    const L = R.params.side;
    // left half: the squares
    const half = { width: canvas.width / 2, height: canvas.height };
    const sq = [[0, 0], [L, 0], [L, L], [0, L], [0, 0]], sqcw = sq.map((q) => [q[0], -q[1]]);
    const allp = [...sq, ...sqcw, ...R._draw.before.cw, ...R._draw.before.ccw];
    const v = view(half, bounds(allp), 30);
    ctx.save();
    ctx.beginPath(); ctx.rect(0, 0, half.width, half.height); ctx.clip();
    grid(ctx, v, "m");
    polyline(ctx, v, sq, "#000", 1, [5, 4]);
    polyline(ctx, v, sqcw, "#000", 1, [2, 3]);
    polyline(ctx, v, R._draw.before.cw, "#d62728", 2);
    polyline(ctx, v, R._draw.before.ccw, "#1f77b4", 2);
    polyline(ctx, v, R._draw.after.cw, "#d6272866", 1.5, [3, 2]);
    polyline(ctx, v, R._draw.after.ccw, "#1f77b466", 1.5, [3, 2]);
    ctx.restore();
    title(ctx, `True paths on a ${fmt(L, 1)} m square`);
    legend(ctx, [["#000", "commanded (odometry's belief)", [5, 4]], ["#d62728", "true, clockwise"], ["#1f77b4", "true, counter-clockwise"], ["#888", "after the correction", [3, 2]]], 12, 36);
    // right half: return errors in cm
    ctx.save();
    ctx.translate(half.width, 0);
    const cm = (e) => [100 * e[0], 100 * e[1]];
    const sets = [
      [R.errors_cw.map(cm), "#d62728", "o"], [R.errors_ccw.map(cm), "#1f77b4", "o"],
      [R.errors_after_cw.map(cm), "#d62728", "s"], [R.errors_after_ccw.map(cm), "#1f77b4", "s"],
    ];
    const pts = [[0, 0]];
    for (const s of sets) pts.push(...s[0]);
    const v2 = view(half, bounds(pts), 30);
    grid(ctx, v2, "cm");
    ctx.strokeStyle = "#000";
    ctx.beginPath(); ctx.moveTo(v2.px(0), 0); ctx.lineTo(v2.px(0), half.height); ctx.moveTo(0, v2.py(0)); ctx.lineTo(half.width, v2.py(0)); ctx.stroke();
    for (const [ps, color, shape] of sets) {
      ctx.fillStyle = color;
      ctx.strokeStyle = color;
      for (const q of ps) {
        if (shape === "o") { ctx.beginPath(); ctx.arc(v2.px(q[0]), v2.py(q[1]), 4, 0, 2 * Math.PI); ctx.fill(); }
        else ctx.strokeRect(v2.px(q[0]) - 4, v2.py(q[1]) - 4, 8, 8);
      }
    }
    for (const [c, color] of [[R.estimate.centroid_cw, "#d62728"], [R.estimate.centroid_ccw, "#1f77b4"]]) {
      const q = cm(c);
      ctx.strokeStyle = color; ctx.lineWidth = 3;
      ctx.beginPath(); ctx.moveTo(v2.px(q[0]) - 9, v2.py(q[1]) - 9); ctx.lineTo(v2.px(q[0]) + 9, v2.py(q[1]) + 9);
      ctx.moveTo(v2.px(q[0]) - 9, v2.py(q[1]) + 9); ctx.lineTo(v2.px(q[0]) + 9, v2.py(q[1]) - 9); ctx.stroke();
    }
    ctx.lineWidth = 1;
    title(ctx, "Return errors [cm]: ● before, □ after, × centroids");
    ctx.restore();
    const E = R.estimate;
    table("umbmark-numbers", [
      ["true E_d, E_b", `${fmt(R.params.E_d, 5)}, ${fmt(R.params.E_b, 5)}`],
      ["estimated E_d", fmt(E.E_d, 6)],
      ["estimated E_b", fmt(E.E_b, 6)],
      ["α, β", `${fmt((E.alpha * 180) / Math.PI, 4)}°, ${fmt((E.beta * 180) / Math.PI, 4)}°`],
      ["centroid cw", `${fmt(100 * E.centroid_cw[0], 3)} cm, ${fmt(100 * E.centroid_cw[1], 3)} cm`],
      ["centroid ccw", `${fmt(100 * E.centroid_ccw[0], 3)} cm, ${fmt(100 * E.centroid_ccw[1], 3)} cm`],
      ["corrected r_L, r_R", `${fmt(R.corrected_geometry.wheel_radius_left, 6)} m, ${fmt(R.corrected_geometry.wheel_radius_right, 6)} m`],
      ["corrected b", `${fmt(R.corrected_geometry.track_width, 6)} m`],
      ["E_max,syst before", `${fmt(100 * R.e_max_before, 3)} cm`],
      ["E_max,syst after", `${fmt(100 * R.e_max_after, 3)} cm`],
      ["reduction", `×${fmt(R.e_max_before / R.e_max_after, 1)}`],
      ["update time", `${fmt(timing.umbmark_ms, 1)} ms`],
    ]);
  }

  // ------------------------------------------------------------------ panel 3: drives
  function computeDrives() {
    const p = { ...params.drives };
    const tw = [p.omega, p.vx, p.vy];
    const drives = {};
    for (const spec of CFG.drives.zoo) {
      let why = null;
      if (!spec.holonomic && tw[2] !== 0) why = "needs v_y = 0";
      else if (!spec.spot_turn && tw[1] === 0 && tw[0] !== 0) why = "cannot turn on the spot";
      const u = why ? null : M.driveInverse(spec.kind === "linear" ? spec : { ...spec, inputs: spec.inputs_map }, tw);
      drives[spec.name] = {
        inputs: u, names: spec.inputs, units: spec.units, unreachable: why, icr_m: M.icr(tw),
        degree_of_mobility: spec.degree_of_mobility, degree_of_steerability: spec.degree_of_steerability,
      };
    }
    results.drives = { params: p, twist: tw, drives };
  }

  function drawDrives() {
    const R = results.drives, canvas = document.getElementById("drives-canvas");
    const ctx = clear(canvas);
    const cols = 4, rows = 3, W = canvas.width / cols, H = canvas.height / rows;
    const rowsOut = [];
    CFG.drives.zoo.forEach((spec, i) => {
      const D = R.drives[spec.name];
      ctx.save();
      ctx.translate((i % cols) * W, Math.floor(i / cols) * H);
      ctx.strokeStyle = "#ccc";
      ctx.strokeRect(0.5, 0.5, W - 1, H - 1);
      ctx.beginPath(); ctx.rect(0, 0, W, H); ctx.clip();
      const wheels = spec.draw;
      const size = 2 * spec.geometry.wheel_radius;
      const pts = wheels.map((w) => [w[0], w[1]]);
      pts.push([0, 0]);
      const icr = D.icr_m;
      const near = icr && Math.hypot(icr[0], icr[1]) < 6;
      if (near) pts.push(icr);
      const bb = bounds(pts);
      const pad = size;
      const textLines = spec.inputs.length > 4 ? Math.ceil(spec.inputs.length / 2) : spec.inputs.length;
      const v = view({ width: W, height: H - 40 - 11 * textLines }, [bb[0] - pad, bb[1] + pad, bb[2] - pad, bb[3] + pad], 12);
      ctx.translate(0, 30);
      // body frame axes
      ctx.strokeStyle = "#999";
      ctx.beginPath(); ctx.moveTo(v.px(0), v.py(0)); ctx.lineTo(v.px(size * 2), v.py(0)); ctx.stroke();
      for (const w of wheels) {
        const h = w[2] + (w[3] >= 0 && D.inputs ? D.inputs[w[3]] : 0);
        const c = Math.cos(h), s = Math.sin(h);
        if (spec.axes_meet && near) {
          ctx.strokeStyle = "#d62728";
          ctx.setLineDash([4, 3]);
          ctx.beginPath(); ctx.moveTo(v.px(w[0]), v.py(w[1])); ctx.lineTo(v.px(icr[0]), v.py(icr[1])); ctx.stroke();
          ctx.setLineDash([]);
        }
        const hl = 0.5 * size, hw = 0.15 * size;
        const corners = [[hl, hw], [-hl, hw], [-hl, -hw], [hl, -hw]].map(([a, b]) => [w[0] + c * a - s * b, w[1] + s * a + c * b]);
        ctx.fillStyle = "#222";
        ctx.beginPath();
        corners.forEach((q, j) => (j ? ctx.lineTo(v.px(q[0]), v.py(q[1])) : ctx.moveTo(v.px(q[0]), v.py(q[1]))));
        ctx.closePath();
        ctx.fill();
      }
      if (near) {
        ctx.fillStyle = "#d62728";
        ctx.font = "18px sans-serif";
        ctx.fillText("★", v.px(icr[0]) - 7, v.py(icr[1]) + 6);
      }
      ctx.restore();
      ctx.save();
      ctx.translate((i % cols) * W, Math.floor(i / cols) * H);
      ctx.font = "bold 12px sans-serif";
      ctx.fillStyle = "#222";
      ctx.fillText(`${spec.name}: δm = ${spec.degree_of_mobility}, δs = ${spec.degree_of_steerability}`, 6, 14);
      ctx.font = "11px sans-serif";
      const icrText = icr ? `ICR (${fmt(icr[0], 2)}, ${fmt(icr[1], 2)}) m` + (near ? "" : " (off the drawing)") : "ICR at infinity (ω = 0)";
      ctx.fillText(icrText, 6, 27);
      ctx.font = "9.5px monospace";
      if (D.unreachable) { ctx.fillStyle = "#b00"; ctx.fillText("unreachable: " + D.unreachable, 6, H - 8); }
      else {
        const per = Math.ceil(D.names.length / 2), two = D.names.length > 4;
        D.names.forEach((nm, j) => {
          const col = two ? Math.floor(j / per) : 0, line = two ? j % per : j;
          const rowsHere = two ? per : D.names.length;
          ctx.fillText(`${nm} ${fmt(D.inputs[j], 3)} ${D.units[j]}`, 6 + (W / 2) * col, H - 6 - 11 * (rowsHere - 1 - line));
        });
      }
      ctx.restore();
      rowsOut.push([spec.name, D.unreachable ? "unreachable: " + D.unreachable : D.names.map((nm, j) => `${nm} ${fmt(D.inputs[j], 3)} ${D.units[j]}`).join(", ")]);
    });
    ctx.font = "bold 13px sans-serif";
    ctx.fillStyle = "#222";
    ctx.fillText("Body twist", 3 * W + 10, 2 * H + 30);
    ctx.font = "13px sans-serif";
    [`ω = ${fmt(R.twist[0], 2)} rad/s`, `v_x = ${fmt(R.twist[1], 2)} m/s`, `v_y = ${fmt(R.twist[2], 2)} m/s`].forEach((t, j) => ctx.fillText(t, 3 * W + 10, 2 * H + 50 + 18 * j));
    table("drives-numbers", rowsOut);
  }

  // ------------------------------------------------------------------ panel 4: fusion
  function computeFusion() {
    const p = { ...params.fusion }, C = CFG.fusion;
    const g = { ...params.growth, path: p.path };
    const { U, model, trueGeom, geom } = growthSetup(g);
    const dt = g.step / C.speed;
    const rng = M.makeRng(C.seed);
    const Un = M.noisyInputs(geom, [g.k_l, g.k_r], U, rng);
    const truth = M.truePath(trueGeom, Un, [0, 0, 0]);
    const F = M.diffMatrix(trueGeom);
    const gyro = Un.map((u) => M.diffTwist(F, u)[0] / dt + rng.normal() * p.gyro_sigma);
    const every = Math.max(1, Math.round(p.gps_period / dt));
    const gps = [];
    for (let k = every; k <= U.length; k += every) gps.push({ k, z: [truth[k][0] + rng.normal() * p.gps_sigma, truth[k][1] + rng.normal() * p.gps_sigma] });
    const gpsAt = new Map(gps.map((f) => [f.k, f.z]));
    let st = { x: [0, 0, 0, 0], P: [[0, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 0]] };
    const path = [[0, 0, 0]], sigma = [0], fixes = [];
    for (let k = 0; k < U.length; k++) {
      st = M.ekfPredict(model, st, U[k]);
      if (p.gyro) st = M.ekfGyro(st, gyro[k], dt, p.gyro_sigma);
      const z = gpsAt.get(k + 1);
      if (p.gps && z) {
        const before = { x: st.x.slice(0, 2), P: [[st.P[0][0], st.P[0][1]], [st.P[1][0], st.P[1][1]]] };
        st = M.ekfGps(st, z, p.gps_sigma);
        fixes.push({ k: k + 1, z, before, after: { x: st.x.slice(0, 2), P: [[st.P[0][0], st.P[0][1]], [st.P[1][0], st.P[1][1]]] } });
      }
      path.push(st.x.slice(0, 3));
      sigma.push(Math.sqrt(st.P[0][0] + st.P[1][1]));
    }
    const dr = M.deadReckon(model, [0, 0, 0], [[0, 0, 0], [0, 0, 0], [0, 0, 0]], U).poses;
    const rmse = (a) => Math.sqrt(a.reduce((s, q, i) => s + (q[0] - truth[i][0]) ** 2 + (q[1] - truth[i][1]) ** 2, 0) / a.length);
    results.fusion = {
      params: p, dt, gps_every_steps: every, gyro_wz: gyro, gps, fixes,
      final_x: st.x, final_P: st.P, rmse_ekf_m: rmse(path), rmse_dead_reckoning_m: rmse(dr),
      _draw: { truth, path, dr, sigma },
    };
  }

  function drawFusion() {
    const R = results.fusion, canvas = document.getElementById("fusion-canvas");
    const ctx = clear(canvas);
    const D = R._draw;
    const ells = R.fixes.map((f) => [M.ellipse(f.before.x, f.before.P, 0.95, 60), M.ellipse(f.after.x, f.after.P, 0.95, 60)]);
    const pts = [...D.truth, ...D.path, ...D.dr];
    for (const e of ells) pts.push(...e[0]);
    const v = view(canvas, bounds(pts));
    grid(ctx, v, "m");
    polyline(ctx, v, D.truth, "#000", 2);
    polyline(ctx, v, D.dr, "#d62728", 1.5);
    polyline(ctx, v, D.path, "#1f77b4", 1.5);
    for (const [b, a] of ells) { polyline(ctx, v, b, "#ff7f0e", 1.2, [4, 3]); polyline(ctx, v, a, "#1f77b4", 1.8); }
    if (R.params.gps) dots(ctx, v, R.gps.map((f) => f.z), "#555", 2.5);
    title(ctx, `Fusion: gyro ${R.params.gyro ? "on" : "off"}, GPS ${R.params.gps ? "on" : "off"}; RMSE EKF ${fmt(R.rmse_ekf_m, 3)} m, dead reckoning ${fmt(R.rmse_dead_reckoning_m, 3)} m`);
    legend(ctx, [["#000", "truth (one Monte Carlo run)"], ["#d62728", "dead reckoning"], ["#1f77b4", "EKF, 95 % ellipse after each fix"], ["#ff7f0e", "95 % ellipse before the fix", [4, 3]]], 12, 36);
    const c2 = document.getElementById("fusion-sigma");
    const ctx2 = clear(c2);
    const n = D.sigma.length, top = Math.max(...D.sigma) * 1.1 || 1;
    ctx2.strokeStyle = "#1f77b4";
    ctx2.lineWidth = 1.5;
    ctx2.beginPath();
    D.sigma.forEach((s, i) => { const x = 50 + (i / (n - 1)) * (c2.width - 70), y = c2.height - 25 - (s / top) * (c2.height - 50); i ? ctx2.lineTo(x, y) : ctx2.moveTo(x, y); });
    ctx2.stroke();
    ctx2.fillStyle = "#222";
    ctx2.font = "11px sans-serif";
    ctx2.fillText(`${fmt(top, 3)} m`, 2, 30);
    ctx2.fillText("0", 30, c2.height - 22);
    ctx2.fillText(`time [s], 0 … ${fmt((n - 1) * R.dt, 1)} s`, c2.width / 2 - 40, c2.height - 6);
    title(ctx2, "EKF position σ = sqrt(P_xx + P_yy) [m]: grows with odometry, drops at each GPS fix");
    table("fusion-numbers", [
      ["step Δt", `${fmt(R.dt, 4)} s`],
      ["GPS fixes", `${R.params.gps ? R.fixes.length : 0} (every ${R.gps_every_steps} steps)`],
      ["final EKF x, y", `${fmt(R.final_x[0])} m, ${fmt(R.final_x[1])} m`],
      ["final σx, σy", `${fmt(Math.sqrt(R.final_P[0][0]))} m, ${fmt(Math.sqrt(R.final_P[1][1]))} m`],
      ["final σθ", `${fmt(Math.sqrt(R.final_P[2][2]))} rad`],
      ["RMSE EKF", `${fmt(R.rmse_ekf_m, 4)} m`],
      ["RMSE dead reckoning", `${fmt(R.rmse_dead_reckoning_m, 4)} m`],
      ["update time", `${fmt(timing.fusion_ms, 1)} ms`],
    ]);
  }

  // ------------------------------------------------------------------ wiring
  function run(name, compute, draw) {
    const t0 = performance.now();
    compute();
    const t1 = performance.now();
    draw();
    const t2 = performance.now();
    timing[name + "_ms"] = t2 - t0;
    timing[name + "_compute_ms"] = t1 - t0;
    timing[name + "_draw_ms"] = t2 - t1;
    draw(); // shows the measured time
  }
  const updGrowth = () => { run("growth", computeGrowth, drawGrowth); run("fusion", computeFusion, drawFusion); };
  const updUmbmark = () => run("umbmark", computeUmbmark, drawUmbmark);
  const updDrives = () => run("drives", computeDrives, drawDrives);
  const updFusion = () => run("fusion", computeFusion, drawFusion);

  const G = CFG.growth;
  addSelect("growth", "path", G.path, updGrowth, "path");
  addSelect("growth", "integrator", G.integrator, updGrowth, "integrator");
  for (const key of ["k_r", "k_l", "wheel_radius", "track_width", "E_d", "E_b", "step", "samples"]) addSlider("growth", key, G[key], updGrowth);
  const U = CFG.umbmark;
  addSelect("umbmark", "method", U.method, updUmbmark, "estimate");
  for (const key of ["E_d", "E_b", "k", "runs", "side"]) addSlider("umbmark", key, U[key], updUmbmark);
  const Dz = CFG.drives;
  for (const key of ["omega", "vx", "vy"]) addSlider("drives", key, Dz[key], updDrives);
  const Fz = CFG.fusion;
  addSelect("fusion", "path", Fz.path, updFusion, "path (robot, integrator and step of the error-growth panel)");
  addCheckbox("fusion", "gyro", Fz.gyro, updFusion, "gyro (yaw rate)");
  addCheckbox("fusion", "gps", Fz.gps, updFusion, "GPS fixes");
  for (const key of ["gyro_sigma", "gps_sigma", "gps_period"]) addSlider("fusion", key, Fz[key], updFusion);

  function plain(obj) {
    return JSON.parse(JSON.stringify(obj, (k, v) => (k === "_draw" ? undefined : typeof v === "number" && !Number.isFinite(v) ? null : v)));
  }
  window.odofuseTeach = {
    state: () => plain({ version: CFG.version, timing, growth: results.growth, umbmark: results.umbmark, drives: results.drives, fusion: results.fusion }),
    config: () => plain(CFG),
  };
  updGrowth();
  updUmbmark();
  updDrives();
})();
