"""Shared test helper: a streaming filter fed wheels and a precise gyro at every step (no
absolute sensor), for the particle filter's collapse and positive-definiteness tests (issue 10,
``tests/test_trust.py`` and ``tests/test_particle_collapse.py``)."""

from __future__ import annotations

import numpy as np

from odofuse.config import config_from_dict


def gyro_localizer(
    backend_cls, steps, particles=20, shrink_at=None, seed=1, name="f", compiled="auto"
):
    """A :class:`~odofuse.estimators.localizer.Localizer` on ``backend_cls`` after ``steps``.

    A differential robot (r 0.04 m, track 0.235 m, ``k_r = k_l = 1e-5``) at 0.2 rad of wheel
    per 20 ms step, with a yaw rate ``w`` following an AR(1) walk; the gyro (sigma 0.005 rad/s,
    bias 0.002 rad/s, estimated from a zero prior) reads it at every step, drawn from
    ``numpy.random.default_rng(seed)``. ``particles`` is passed to a
    :class:`~odofuse.estimators.particle.ParticleBackend`; at step ``shrink_at`` its cloud is
    shrunk 1000-fold about its mean (a collapse, seen from the next pose on); ``compiled`` is
    its ``options.particle.compiled`` (``auto``: numpy, as for any live Localizer).
    """
    from odofuse.estimators.common import augmented_prior, state_layout
    from odofuse.estimators.localizer import Localizer
    from odofuse.estimators.particle import ParticleBackend
    from odofuse.measurements import GyroYawRate
    from odofuse.motion import motion_model_from_config

    cfg = config_from_dict(
        {
            "log": "x",
            "robot": {"drive": "differential", "wheel_radius": 0.04, "track_width": 0.235},
            "motion": {"k_r": 1e-5, "k_l": 1e-5},
        }
    )
    motion = motion_model_from_config(cfg)
    gyro = GyroYawRate("gyro", 0.005, gate=0.999)
    names, index = state_layout({"gyro": gyro})
    gyro = gyro.bind(index)
    x0, P0, walk = augmented_prior({"gyro": gyro}, names, np.zeros(3), np.eye(3) * 1e-4)
    opts = (
        {"particles": particles, "compiled": compiled} if backend_cls is ParticleBackend else None
    )
    args = (motion, {"gyro": gyro}, x0, P0, walk) + ((opts,) if opts else ())
    backend = backend_cls(*args)
    loc = Localizer(backend, {"gyro": gyro}, 0.0, late_window=0.0, name=name)
    rng = np.random.default_rng(seed)
    dt, w = 0.02, 0.0
    for k in range(1, steps + 1):
        w = 0.99 * w + rng.normal(0, 0.05)
        u = np.array([0.2 - 0.1175 * w, 0.2 + 0.1175 * w]) * dt / 0.04
        loc.add_measurement("gyro", {"t": k * dt, "wz": w + 0.002 + rng.normal(0, 0.005)})
        loc.add_odometry(k * dt, u)
        if k == shrink_at:
            m = backend.mean()
            backend.X[:, :3] = m[:3] + 1e-3 * (backend.X[:, :3] - m[:3])
    return loc
