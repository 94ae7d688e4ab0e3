/*
 * odofuse teaching model: the library's equations, once, in plain JavaScript.
 *
 * Every function names the Python function it mirrors; tests/test_teach_page.py checks in a
 * real browser that the numbers agree with the library within 1e-9 relative.
 *
 * Conventions (as in odofuse): a pose is [x, y, theta] (m, m, rad); a body twist is
 * [omega, v_x, v_y] integrated over one step (Delta t = 1, so rad and m per step); a
 * differential drive's inputs are the wheel angle increments [left, right] (rad).
 *
 * Sources (shared/sources): Siegwart & Nourbakhsh ch. 5 (004_f4547100a083f338.txt) for the
 * error model P' = F_p P F_p^T + F_u Sigma_u F_u^T with var(ds_i) = k_i |ds_i|; Modern
 * Robotics 13.34-13.35 (000_96a7e9c96987202e.txt) for the drive matrix and the twist
 * exponential; Politecnico slides (003_73fced8ec7c15fe5.txt) for Euler / RK2 / exact;
 * Borenstein & Feng (1996), via 002_88fc37db58155723.txt, for UMBmark.
 */
(function (root) {
  "use strict";
  const PI = Math.PI;
  const TWO_PI = 2.0 * Math.PI;

  // ---------------------------------------------------------------- SE(2): odofuse/se2.py
  /** se2.wrap: angle to [-pi, pi), Python's floored modulo. */
  function wrap(a) {
    let r = (a + PI) % TWO_PI;
    if (r < 0) r += TWO_PI;
    return r - PI;
  }

  /** se2.compose: head-to-tail a (+) b. */
  function compose(a, b) {
    const c = Math.cos(a[2]), s = Math.sin(a[2]);
    return [a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], wrap(a[2] + b[2])];
  }

  /** se2.J_compose: F_p = [[1,0,-dy_w],[0,1,dx_w],[0,0,1]], J_b = blockdiag(R(th_a), 1). */
  function J_compose(a, b) {
    const c = Math.cos(a[2]), s = Math.sin(a[2]);
    const dxw = c * b[0] - s * b[1];
    const dyw = s * b[0] + c * b[1];
    return {
      Fp: [[1, 0, -dyw], [0, 1, dxw], [0, 0, 1]],
      Jb: [[c, -s, 0], [s, c, 0], [0, 0, 1]],
    };
  }

  const SERIES_BELOW = 5e-2; // se2._SERIES_BELOW

  /** se2._exp_coefficients: A = sin w / w, B = (1 - cos w)/w from the half angle, and dA, dB. */
  function expCoefficients(w) {
    const half = 0.5 * w;
    const sh = Math.sin(half), ch = Math.cos(half);
    const sincHalf = w === 0.0 ? 1.0 : sh / half;
    const A = sincHalf * ch, B = sincHalf * sh;
    const small = Math.abs(w) < SERIES_BELOW;
    const ws = small ? 1.0 : w;
    const inv2 = 1.0 / (ws * ws);
    const s = 2.0 * sh * ch, omc = 2.0 * sh * sh;
    const w2 = w * w;
    let dA, dB;
    if (small) {
      dA = w * (-1.0 / 3.0 + w2 * (1.0 / 30.0 + w2 * (-1.0 / 840.0 + w2 / 45360.0)));
      dB = 0.5 + w2 * (-1.0 / 8.0 + w2 * (1.0 / 144.0 + w2 * (-1.0 / 5760.0 + w2 / 403200.0)));
    } else {
      dA = (ws * (1.0 - omc) - s) * inv2;
      dB = (ws * s - omc) * inv2;
    }
    return [A, B, dA, dB];
  }

  /** se2.exp: relative pose of a constant body twist over unit time (MR 13.35). */
  function exp(tw) {
    const [A, B] = expCoefficients(tw[0]);
    return [A * tw[1] - B * tw[2], B * tw[1] + A * tw[2], tw[0]];
  }

  // ------------------------------------------------- integrators: odofuse/motion/integrators.py
  /** integrators.body_increment: relative pose of one step and d delta / d twist. */
  function bodyIncrement(tw, integrator) {
    const w = tw[0], vx = tw[1], vy = tw[2];
    if (integrator === "exact") {
      const [A, B, dA, dB] = expCoefficients(w);
      return {
        d: [A * vx - B * vy, B * vx + A * vy, w],
        J: [[dA * vx - dB * vy, A, -B], [dB * vx + dA * vy, B, A], [1, 0, 0]],
      };
    }
    if (integrator === "euler") {
      return { d: [vx, vy, w], J: [[0, 1, 0], [0, 0, 1], [1, 0, 0]] };
    }
    if (integrator === "rk2" || integrator === "euler_end") {
      const f = integrator === "rk2" ? 0.5 : 1.0;
      const c = Math.cos(f * w), s = Math.sin(f * w);
      return {
        d: [c * vx - s * vy, s * vx + c * vy, w],
        J: [[f * (-s * vx - c * vy), c, -s], [f * (c * vx - s * vy), s, c], [1, 0, 0]],
      };
    }
    throw new Error("unknown integrator " + integrator);
  }

  // ------------------------------------------------------ drives: odofuse/drives/differential.py
  /** Differential.side_matrix: twist = F [left, right] (MR 13.34, 2d = track width). */
  function diffMatrix(geom) {
    const rl = geom.wheel_radius_left ?? geom.wheel_radius;
    const rr = geom.wheel_radius_right ?? geom.wheel_radius;
    const d = 0.5 * geom.track_width;
    return [[-rl / (2 * d), rr / (2 * d)], [rl / 2, rr / 2], [0, 0]];
  }

  function diffTwist(F, u) {
    return [F[0][0] * u[0] + F[0][1] * u[1], F[1][0] * u[0] + F[1][1] * u[1], 0.0];
  }

  /** _LinearDrive.inverse for the differential drive (pinv(F) twist, solved in closed form). */
  function diffInverse(geom, tw) {
    const rl = geom.wheel_radius_left ?? geom.wheel_radius;
    const rr = geom.wheel_radius_right ?? geom.wheel_radius;
    const d = 0.5 * geom.track_width;
    return [(tw[1] - d * tw[0]) / rl, (tw[1] + d * tw[0]) / rr];
  }

  /** simulate.true_geometry for the differential drive: E_d splits the radii keeping their
   * mean (Borenstein & Feng), E_b scales the track width. */
  function trueGeometry(geom, E_d, E_b) {
    const g = { ...geom };
    const r = g.wheel_radius;
    if (E_d !== 1.0) {
      const rl = g.wheel_radius_left ?? r, rr = g.wheel_radius_right ?? r;
      g.wheel_radius_left = (rl * 2.0) / (E_d + 1.0);
      g.wheel_radius_right = (rr * 2.0) / (1.0 / E_d + 1.0);
    }
    if (E_b !== 1.0) g.track_width = g.track_width * E_b;
    return g;
  }

  // ------------------------------------------------ error model: odofuse/motion/noise.py
  /** OdometryErrorModel.variances: var(u_i) = k_i |travel_i| / r_i^2 (Siegwart ch. 5). */
  function inputVariances(geom, k, u) {
    const rl = geom.wheel_radius_left ?? geom.wheel_radius;
    const rr = geom.wheel_radius_right ?? geom.wheel_radius;
    return [(k[0] * (Math.abs(u[0]) * rl)) / (rl * rl), (k[1] * (Math.abs(u[1]) * rr)) / (rr * rr)];
  }

  // ------------------------------------------------------ motion model: odofuse/motion/model.py
  /** MotionModel.predict: pose (+) delta(u), P' = F_p P F_p^T + F_u Sigma_u F_u^T. */
  function predict(model, pose, P, u) {
    const F = diffMatrix(model.geom);
    const tw = diffTwist(F, u);
    const inc = bodyIncrement(tw, model.integrator);
    const Jdu = matmul(inc.J, F); // 3 x 2
    const { Fp, Jb } = J_compose(pose, inc.d);
    const Fu = matmul(Jb, Jdu);
    const v = inputVariances(model.geom, model.k, u);
    const A = matmul(matmul(Fp, P), transpose(Fp));
    const Pn = [[0, 0, 0], [0, 0, 0], [0, 0, 0]];
    for (let i = 0; i < 3; i++)
      for (let j = 0; j < 3; j++)
        Pn[i][j] = A[i][j] + (Fu[i][0] * v[0] * Fu[j][0] + Fu[i][1] * v[1] * Fu[j][1]);
    return { pose: compose(pose, inc.d), P: sym(Pn), Fp, Fu };
  }

  /** model.dead_reckon: poses (N+1) and covariances (N+1) of a whole input sequence. */
  function deadReckon(model, pose0, P0, U) {
    const poses = [pose0.slice()];
    const covs = [P0.map((r) => r.slice())];
    let pose = pose0.slice(), P = P0.map((r) => r.slice());
    for (const u of U) {
      const out = predict(model, pose, P, u);
      pose = out.pose;
      P = out.P;
      poses.push(pose);
      covs.push(P);
    }
    return { poses, covs };
  }

  // --------------------------------------------------------- paths: odofuse/teaching/paths.py
  function segments(length, perStep) {
    return Math.max(1, Math.ceil(Math.abs(length) / perStep - 1e-9));
  }
  function repeat(tw, n) {
    return Array.from({ length: n }, () => tw.slice());
  }
  /** paths._straight */
  function straight(distance, v, dt) {
    const n = segments(distance, v * dt);
    return repeat([0.0, distance / n, 0.0], n);
  }
  /** paths._turn */
  function turn(angle, w, dt) {
    if (Math.abs(angle) < 1e-12) return [];
    const n = segments(angle, w * dt);
    return repeat([angle / n, 0.0, 0.0], n);
  }
  /** paths._arc */
  function arc(angle, radius, v, dt) {
    const length = Math.abs(angle) * radius;
    const n = segments(length, v * dt);
    return repeat([angle / n, length / n, 0.0], n);
  }
  /** paths.square_twists (corner_radius 0, one lap) */
  function squareTwists(side, direction, speed, turnRate, dt) {
    const sgn = direction === "ccw" ? 1.0 : -1.0;
    const out = [];
    for (let i = 0; i < 4; i++) {
      out.push(...straight(side, speed, dt));
      out.push(...turn((sgn * PI) / 2, turnRate, dt));
    }
    return out;
  }
  /** paths.figure_eight_twists (one lap) */
  function figureEightTwists(radius, speed, dt) {
    return [...arc(2 * PI, radius, speed, dt), ...arc(-2 * PI, radius, speed, dt)];
  }

  // --------------------------------------------------------- UMBmark: odofuse/teaching/umbmark.py
  /** umbmark.square_return_error: exact return point of Borenstein's model on one square. */
  function squareReturnError(alpha, beta, side, direction) {
    const sgn = direction === "ccw" ? 1.0 : -1.0;
    let pose = [0, 0, 0];
    const leg = exp([beta, side, 0.0]);
    const tr = [0.0, 0.0, sgn * (PI / 2 - alpha)];
    for (let i = 0; i < 4; i++) pose = compose(compose(pose, leg), tr);
    return [pose[0], pose[1]];
  }
  /** umbmark._linear_alpha_beta: Borenstein's linear alpha, beta from x and y, averaged. */
  function linearAlphaBeta(cCw, cCcw, L) {
    const [xCw, yCw] = cCw, [xCcw, yCcw] = cCcw;
    const alpha = 0.5 * ((xCw + xCcw) / (-4 * L) + (yCw - yCcw) / (-4 * L));
    const beta = 0.5 * ((xCw - xCcw) / (-4 * L) + (yCw + yCcw) / (-4 * L));
    return [alpha, beta];
  }
  function centroid(errs) {
    let x = 0, y = 0;
    for (const e of errs) { x += e[0]; y += e[1]; }
    return [x / errs.length, y / errs.length];
  }
  /** umbmark.umbmark_estimate (method "exact" or "linear"). */
  function umbmarkEstimate(errorsCw, errorsCcw, side, trackWidth, method) {
    const cCw = centroid(errorsCw), cCcw = centroid(errorsCcw);
    const L = side;
    let [alpha, beta] = linearAlphaBeta(cCw, cCcw, L);
    let R;
    if (method === "linear") {
      R = Math.abs(beta) < 1e-15 ? Infinity : L / 2 / Math.sin(beta / 2);
    } else {
      for (let it = 0; it < 50; it++) {
        const sCw = squareReturnError(alpha, beta, L, "cw");
        const sCcw = squareReturnError(alpha, beta, L, "ccw");
        const [da, db] = linearAlphaBeta(
          [cCw[0] - sCw[0], cCw[1] - sCw[1]], [cCcw[0] - sCcw[0], cCcw[1] - sCcw[1]], L);
        alpha += da;
        beta += db;
        if (Math.abs(da) + Math.abs(db) < 1e-13) break;
      }
      R = Math.abs(beta) < 1e-15 ? Infinity : L / beta;
    }
    const E_b = PI / 2 / (PI / 2 - alpha);
    const b = E_b * trackWidth;
    const E_d = R === Infinity ? 1.0 : (R + b / 2) / (R - b / 2);
    return { alpha, beta, E_b, E_d, R: R === Infinity ? null : R, centroid_cw: cCw, centroid_ccw: cCcw };
  }
  /** umbmark.corrected_geometry: r_L <- 2/(E_d+1) r_L, r_R <- 2/(1/E_d+1) r_R, b <- E_b b. */
  function correctedGeometry(geom, E_d, E_b) {
    const g = { ...geom };
    const r = g.wheel_radius;
    g.wheel_radius_left = ((g.wheel_radius_left || r) * 2.0) / (E_d + 1.0);
    g.wheel_radius_right = ((g.wheel_radius_right || r) * 2.0) / (1.0 / E_d + 1.0);
    g.track_width = g.track_width * E_b;
    return g;
  }
  /** umbmark.systematic_return_error: E_max,syst = max(|c_cw|, |c_ccw|). */
  function systematicReturnError(errorsCw, errorsCcw) {
    const a = centroid(errorsCw), b = centroid(errorsCcw);
    return Math.max(Math.hypot(a[0], a[1]), Math.hypot(b[0], b[1]));
  }

  // ---------------------------------------------------------- simulation: simulate.simulate
  /** The truth of simulate.simulate: the wheels u (rad per step) move the robot through the
   * true geometry by the exact twist exponential; headings and positions are running sums. */
  function truePath(trueGeom, U, pose0) {
    const F = diffMatrix(trueGeom);
    const out = [pose0.slice()];
    let x = pose0[0], y = pose0[1], heading = pose0[2];
    for (const u of U) {
      const d = exp(diffTwist(F, u));
      const c = Math.cos(heading), s = Math.sin(heading);
      x += c * d[0] - s * d[1];
      y += s * d[0] + c * d[1];
      heading += d[2];
      out.push([x, y, wrap(heading)]);
    }
    return out;
  }

  /** Wheel travel noise of simulate.simulate: u_i += N(0,1) sqrt(k_i |u_i r_i|) / r_i. */
  function noisyInputs(geom, k, U, rng) {
    const rl = geom.wheel_radius_left ?? geom.wheel_radius;
    const rr = geom.wheel_radius_right ?? geom.wheel_radius;
    return U.map((u) => [
      u[0] + (rng.normal() * Math.sqrt(k[0] * Math.abs(u[0] * rl))) / rl,
      u[1] + (rng.normal() * Math.sqrt(k[1] * Math.abs(u[1] * rr))) / rr,
    ]);
  }

  /** umbmark.return_error with the start at the origin heading +x: p_true - p_odometry. */
  function returnError(truthEnd, odoEnd) {
    return [truthEnd[0] - odoEnd[0], truthEnd[1] - odoEnd[1]];
  }

  // --------------------------------------------- EKF: odofuse/estimators/ekf.py (EkfBackend)
  /* State [x, y, theta, theta_ref]: theta_ref is the gyro's cloned heading
   * (measurements/gyro.py GyroYawRate, calibrate=False: h = wrap(theta - theta_ref)/dt).
   * The prediction is MotionModel.predict on the pose block (identity on theta_ref); the
   * update is filterpy's ExtendedKalmanFilter.update (Joseph form). */
  function ekfPredict(model, st, u) {
    const P3 = [0, 1, 2].map((i) => [0, 1, 2].map((j) => st.P[i][j]));
    const out = predict(model, st.x.slice(0, 3), P3, u);
    // the cross covariance with theta_ref moves by F_p (identity on theta_ref)
    const cross = [0, 1, 2].map((i) => st.P[i][3]);
    const c = [0, 1, 2].map((i) => out.Fp[i][0] * cross[0] + out.Fp[i][1] * cross[1] + out.Fp[i][2] * cross[2]);
    const P = [
      [out.P[0][0], out.P[0][1], out.P[0][2], c[0]],
      [out.P[1][0], out.P[1][1], out.P[1][2], c[1]],
      [out.P[2][0], out.P[2][1], out.P[2][2], c[2]],
      [c[0], c[1], c[2], st.P[3][3]],
    ];
    return { x: [...out.pose, st.x[3]], P };
  }

  /** filterpy ExtendedKalmanFilter.update: K = P H^T S^-1, x += K y, Joseph-form P. */
  function ekfUpdate(st, z, hx, H, R) {
    const n = st.x.length;
    const PHt = matmul(st.P, transpose(H));
    const S = matmul(H, PHt).map((row, i) => row.map((v, j) => v + R[i][j]));
    const SI = inv(S);
    const K = matmul(PHt, SI);
    const y = z.map((v, i) => v - hx[i]);
    const x = st.x.map((v, i) => v + K[i].reduce((acc, kij, j) => acc + kij * y[j], 0));
    const IKH = eye(n).map((row, i) => row.map((v, j) => v - K[i].reduce((acc, kik, k) => acc + kik * H[k][j], 0)));
    const A = matmul(matmul(IKH, st.P), transpose(IKH));
    const KRKt = matmul(matmul(K, R), transpose(K));
    const P = A.map((row, i) => row.map((v, j) => v + KRKt[i][j]));
    x[2] = wrap(x[2]);
    const nis = y.reduce((acc, yi, i) => acc + yi * SI[i].reduce((a2, s, j) => a2 + s * y[j], 0), 0);
    return { x, P, nis };
  }

  /** GpsPosition: z = [x, y], H = [I_2 0]. */
  function ekfGps(st, z, sigma) {
    const H = [[1, 0, 0, 0], [0, 1, 0, 0]];
    return ekfUpdate(st, z, [st.x[0], st.x[1]], H, [[sigma * sigma, 0], [0, sigma * sigma]]);
  }

  /** GyroYawRate (calibrate=False): z = wz, h = wrap(theta - theta_ref)/dt, then the clone
   * theta_ref <- theta (EkfBackend.clone(3, 2)). */
  function ekfGyro(st, wz, dt, sigma) {
    const H = [[0, 0, 1 / dt, -1 / dt]];
    const hx = [wrap(st.x[2] - st.x[3]) / dt];
    const out = ekfUpdate(st, [wz], hx, H, [[sigma * sigma]]);
    return ekfClone(out);
  }

  /** EkfBackend.clone(3, 2): theta_ref becomes a copy of theta (x and P). */
  function ekfClone(st) {
    const x = st.x.slice(), P = st.P.map((r) => r.slice());
    x[3] = x[2];
    for (let j = 0; j < 4; j++) P[3][j] = P[2][j];
    for (let i = 0; i < 4; i++) P[i][3] = P[i][2];
    P[3][3] = P[2][2];
    return { x, P, nis: st.nis };
  }

  // ------------------------------------------------------------- drive zoo: odofuse/drives
  /** base.icr: the ICR (-v_y/omega, v_x/omega) in the body frame, null for omega = 0. */
  function icr(tw) {
    return tw[0] === 0.0 ? null : [-tw[2] / tw[0], tw[1] / tw[0]];
  }
  /** base._steered_wheel_inverse: rolling speed and steering angle in (-pi/2, pi/2]. */
  function steeredWheelInverse(vxw, vyw) {
    const s = vxw < 0.0 ? -1.0 : 1.0;
    return [s * Math.hypot(vxw, vyw), Math.atan2(s * vyw, s * vxw)];
  }
  /** Drive.inverse for a body twist per second: linear drives u = pinv(F) twist
   * (_LinearDrive.inverse; pinv computed by numpy from the library's F); steered drives wheel
   * by wheel, the contact point at (x, y) moving by (v_x - omega y, v_y + omega x)
   * (Tricycle, Bicycle, Ackermann, Swerve, Car, CarAckermann .inverse). */
  function driveInverse(spec, tw) {
    if (spec.kind === "linear") return spec.pinv.map((row) => row[0] * tw[0] + row[1] * tw[1] + row[2] * tw[2]);
    return spec.inputs.map((inp) => {
      const [x, y] = spec.wheels[inp.wheel];
      const [speed, delta] = steeredWheelInverse(tw[1] - tw[0] * y, tw[2] + tw[0] * x);
      return inp.type === "rate" ? speed / inp.radius : delta;
    });
  }

  // ------------------------------------------------------------------------- NEES, ellipses
  /** NEES of error e against covariance P (3 dof): e^T P^-1 e. */
  function nees(e, P) {
    const Pi = inv(P);
    let s = 0;
    for (let i = 0; i < e.length; i++) for (let j = 0; j < e.length; j++) s += e[i] * Pi[i][j] * e[j];
    return s;
  }

  /** Wilson-Hilferty quantile of chi-square with dof degrees of freedom (relative error
   * below 1e-4 for dof > 100); the 95 % bounds of the mean NEES of n runs
   * (figures.nees_bounds, Bar-Shalom 5.4) use dof = 3 n. */
  function chi2Quantile(p, dof) {
    const z = normalQuantile(p);
    const h = 2 / (9 * dof);
    return dof * Math.pow(1 - h + z * Math.sqrt(h), 3);
  }
  function neesBounds(n, dim, prob) {
    const dof = n * dim;
    return [chi2Quantile(0.5 * (1 - prob), dof) / n, chi2Quantile(0.5 * (1 + prob), dof) / n];
  }
  /** Acklam's rational approximation of the standard normal quantile (|error| < 1.2e-9). */
  function normalQuantile(p) {
    const a = [-3.969683028665376e1, 2.209460984245205e2, -2.759285104469687e2, 1.38357751867269e2, -3.066479806614716e1, 2.506628277459239];
    const b = [-5.447609879822406e1, 1.615858368580409e2, -1.556989798598866e2, 6.680131188771972e1, -1.328068155288572e1];
    const c = [-7.784894002430293e-3, -3.223964580411365e-1, -2.400758277161838, -2.549732539343734, 4.374664141464968, 2.938163982698783];
    const d = [7.784695709041462e-3, 3.224671290700398e-1, 2.445134137142996, 3.754408661907416];
    const pl = 0.02425;
    if (p < pl) {
      const q = Math.sqrt(-2 * Math.log(p));
      return (((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5]) / ((((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1);
    }
    if (p > 1 - pl) return -normalQuantile(1 - p);
    const q = p - 0.5, r = q * q;
    return ((((((a[0] * r + a[1]) * r + a[2]) * r + a[3]) * r + a[4]) * r + a[5]) * q) / (((((b[0] * r + b[1]) * r + b[2]) * r + b[3]) * r + b[4]) * r + 1);
  }

  /** Outline of the prob confidence ellipse of a 2-D Gaussian (demos.figures._ellipse). */
  function ellipse(mean, C, prob, points) {
    const r = Math.sqrt(-2.0 * Math.log(1.0 - prob));
    const a = C[0][0], b = C[0][1], d = C[1][1];
    const tr = 0.5 * (a + d), det = a * d - b * b;
    const disc = Math.sqrt(Math.max(tr * tr - det, 0));
    const l1 = Math.max(tr + disc, 0), l2 = Math.max(tr - disc, 0);
    const ang = 0.5 * Math.atan2(2 * b, a - d);
    const ca = Math.cos(ang), sa = Math.sin(ang);
    const out = [];
    for (let i = 0; i <= points; i++) {
      const t = (TWO_PI * i) / points;
      const ex = r * Math.sqrt(l1) * Math.cos(t), ey = r * Math.sqrt(l2) * Math.sin(t);
      out.push([mean[0] + ca * ex - sa * ey, mean[1] + sa * ex + ca * ey]);
    }
    return out;
  }

  // ---------------------------------------------------------------------- seeded PRNG
  /** mulberry32 uniforms and Marsaglia's polar normals: the page's own seeded generator (its
   * Monte Carlo is compared with the library statistically, never draw by draw). */
  function makeRng(seed) {
    let a = seed >>> 0;
    let spare = null;
    function uniform() {
      a = (a + 0x6d2b79f5) >>> 0;
      let t = a;
      t = Math.imul(t ^ (t >>> 15), t | 1);
      t ^= t + Math.imul(t ^ (t >>> 7), t | 61);
      return ((t ^ (t >>> 14)) >>> 0) / 4294967296;
    }
    function normal() {
      if (spare !== null) { const s = spare; spare = null; return s; }
      let u, v, q;
      do {
        u = 2 * uniform() - 1;
        v = 2 * uniform() - 1;
        q = u * u + v * v;
      } while (q >= 1 || q === 0);
      const f = Math.sqrt((-2 * Math.log(q)) / q);
      spare = v * f;
      return u * f;
    }
    return { uniform, normal };
  }

  // ---------------------------------------------------------------------- small linear algebra
  function matmul(A, B) {
    const n = A.length, m = B[0].length, k = B.length;
    const C = [];
    for (let i = 0; i < n; i++) {
      const row = new Array(m).fill(0);
      for (let j = 0; j < m; j++) {
        let s = 0;
        for (let l = 0; l < k; l++) s += A[i][l] * B[l][j];
        row[j] = s;
      }
      C.push(row);
    }
    return C;
  }
  function transpose(A) {
    return A[0].map((_, j) => A.map((row) => row[j]));
  }
  function eye(n) {
    return Array.from({ length: n }, (_, i) => Array.from({ length: n }, (_, j) => (i === j ? 1 : 0)));
  }
  function sym(P) {
    return P.map((row, i) => row.map((v, j) => 0.5 * (v + P[j][i])));
  }
  /** Gauss-Jordan inverse with partial pivoting (small matrices). */
  function inv(M) {
    const n = M.length;
    const A = M.map((row, i) => [...row, ...eye(n)[i]]);
    for (let c = 0; c < n; c++) {
      let p = c;
      for (let r = c + 1; r < n; r++) if (Math.abs(A[r][c]) > Math.abs(A[p][c])) p = r;
      [A[c], A[p]] = [A[p], A[c]];
      const piv = A[c][c];
      for (let j = 0; j < 2 * n; j++) A[c][j] /= piv;
      for (let r = 0; r < n; r++) {
        if (r === c) continue;
        const f = A[r][c];
        if (f !== 0) for (let j = 0; j < 2 * n; j++) A[r][j] -= f * A[c][j];
      }
    }
    return A.map((row) => row.slice(n));
  }

  root.odofuseModel = {
    wrap, compose, J_compose, exp, expCoefficients, bodyIncrement,
    diffMatrix, diffTwist, diffInverse, trueGeometry, inputVariances,
    predict, deadReckon, segments, straight, turn, arc, squareTwists, figureEightTwists,
    squareReturnError, linearAlphaBeta, umbmarkEstimate, correctedGeometry,
    systematicReturnError, truePath, noisyInputs, returnError, centroid,
    ekfPredict, ekfUpdate, ekfGps, ekfGyro, ekfClone,
    icr, steeredWheelInverse, driveInverse,
    nees, neesBounds, chi2Quantile, normalQuantile, ellipse, makeRng,
    matmul, transpose, inv,
  };
})(typeof window !== "undefined" ? window : globalThis);
