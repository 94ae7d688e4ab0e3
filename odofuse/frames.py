r"""Mobile-manipulator frames, Modern Robotics 13.5 (``000_96a7e9c96987202e.txt``).

With the fixed space frame {s}, the chassis frame {b}, the arm base frame {0} and the
end-effector frame {e}, the end-effector configuration is

.. math::

    X(q, \theta) = T_{se}(q, \theta) = T_{sb}(q)\, T_{b0}\, T_{0e}(\theta) \in SE(3).

Modern Robotics writes the chassis configuration ``q = (phi, x, y)``; odofuse poses are
``[x, y, theta]`` (``docs/architecture.md``), so ``q`` here is ``[x, y, phi]``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = ["T_sb", "end_effector"]


def _check_T(T: np.ndarray, what: str) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if T.shape[-2:] != (4, 4):
        raise ValueError(f"{what} must be a 4x4 homogeneous transform, got shape {T.shape}")
    if not np.isfinite(T).all():
        raise ValueError(f"{what} has non-finite entries")
    if not np.allclose(T[..., 3, :], [0.0, 0.0, 0.0, 1.0]):
        raise ValueError(f"{what}: last row must be [0, 0, 0, 1]")
    R = T[..., :3, :3]
    I3 = np.broadcast_to(np.eye(3), R.shape)
    if not np.allclose(np.swapaxes(R, -1, -2) @ R, I3, atol=1e-9):
        raise ValueError(f"{what}: rotation block is not orthonormal")
    return T


def T_sb(q, z: float = 0.0) -> np.ndarray:
    """Chassis frame {b} in the space frame {s} for a planar pose.

    Parameters
    ----------
    q : array_like, shape (3,) or (N, 3)
        ``[x, y, phi]`` (m, m, rad), world frame.
    z : float, optional
        Height of {b} above the floor, m (Modern Robotics uses 0.0963 m for the KUKA youBot).

    Returns
    -------
    ndarray, shape (4, 4) or (N, 4, 4)
        ``[[cos phi, -sin phi, 0, x], [sin phi, cos phi, 0, y], [0, 0, 1, z], [0, 0, 0, 1]]``.
    """
    q = np.asarray(q, dtype=float)
    if q.shape[-1:] != (3,) or q.ndim not in (1, 2):
        raise ValueError(f"q must have shape (3,) or (N, 3) [x, y, phi], got {q.shape}")
    if not np.isfinite(q).all() or not np.isfinite(z):
        raise ValueError("q and z must be finite")
    c, s = np.cos(q[..., 2]), np.sin(q[..., 2])
    T = np.zeros(q.shape[:-1] + (4, 4))
    T[..., 0, 0], T[..., 0, 1], T[..., 0, 3] = c, -s, q[..., 0]
    T[..., 1, 0], T[..., 1, 1], T[..., 1, 3] = s, c, q[..., 1]
    T[..., 2, 2], T[..., 2, 3] = 1.0, float(z)
    T[..., 3, 3] = 1.0
    return T


def end_effector(
    q,
    T_b0,
    T_0e: np.ndarray | Callable[[np.ndarray], np.ndarray],
    theta=None,
    z: float = 0.0,
) -> np.ndarray:
    """End-effector configuration ``X = T_sb(q) T_b0 T_0e(theta)`` (Modern Robotics 13.5).

    Parameters
    ----------
    q : array_like, shape (3,) or (N, 3)
        Chassis pose ``[x, y, phi]``.
    T_b0 : array_like, shape (4, 4)
        Fixed offset of the arm base {0} in the chassis frame {b}.
    T_0e : array_like (4, 4) or callable
        End-effector in {0}: a fixed transform, or the arm's forward kinematics
        ``theta -> (4, 4)`` (called once per chassis pose when ``theta`` has a row per pose).
    theta : array_like, optional
        Joint angles passed to a callable ``T_0e``: shape ``(k,)`` (same for every pose) or
        ``(N, k)`` (one row per pose). Required when ``T_0e`` is callable.
    z : float, optional
        Height of {b}, see :func:`T_sb`.

    Returns
    -------
    ndarray, shape (4, 4) or (N, 4, 4)
        ``T_se`` in the space frame.
    """
    Tsb = T_sb(q, z)
    Tb0 = _check_T(T_b0, "T_b0")
    if Tb0.shape != (4, 4):
        raise ValueError(f"T_b0 must have shape (4, 4), got {Tb0.shape}")
    if callable(T_0e):
        if theta is None:
            raise ValueError("theta is required when T_0e is a callable (arm forward kinematics)")
        th = np.asarray(theta, dtype=float)
        if th.ndim == 2:
            if Tsb.ndim != 3 or th.shape[0] != Tsb.shape[0]:
                raise ValueError(
                    f"theta with shape {th.shape} needs one chassis pose per row, "
                    f"got q with shape {np.shape(q)}"
                )
            T0e = np.stack([_check_T(T_0e(row), "T_0e(theta)") for row in th])
        else:
            T0e = _check_T(T_0e(th), "T_0e(theta)")
    else:
        if theta is not None:
            raise ValueError("theta given but T_0e is a fixed transform, not a callable")
        T0e = _check_T(T_0e, "T_0e")
        if T0e.shape != (4, 4):
            raise ValueError(f"T_0e must have shape (4, 4), got {T0e.shape}")
    return Tsb @ Tb0 @ T0e
