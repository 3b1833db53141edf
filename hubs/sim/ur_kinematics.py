"""UR10 kinematics for the fake controller: forward kinematics (DH) and damped least-squares IK.

Poses are x, y, z (m) and a rotation vector (rad), as RTDE's ``actual_TCP_pose``.
"""

from __future__ import annotations

import math

from hubs.protocols.ur import rotation_matrix

UR10_DH = (  # d, a, alpha
    (0.1273, 0.0, math.pi / 2),
    (0.0, -0.612, 0.0),
    (0.0, -0.5723, 0.0),
    (0.163941, 0.0, math.pi / 2),
    (0.1157, 0.0, -math.pi / 2),
    (0.0922, 0.0, 0.0),
)
Mat = list[list[float]]


def _matmul(a: Mat, b: Mat) -> Mat:
    return [[sum(a[i][k] * b[k][j] for k in range(4)) for j in range(4)] for i in range(4)]


def forward(q: list[float]) -> Mat:
    t: Mat = [[1.0 if i == j else 0.0 for j in range(4)] for i in range(4)]
    for theta, (d, a, alpha) in zip(q, UR10_DH, strict=True):
        ct, st, ca, sa = math.cos(theta), math.sin(theta), math.cos(alpha), math.sin(alpha)
        t = _matmul(t, [[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st], [0, sa, ca, d], [0, 0, 0, 1]])
    return t


def rotvec_of(r: Mat) -> list[float]:
    cos = max(-1.0, min(1.0, (r[0][0] + r[1][1] + r[2][2] - 1) / 2))
    angle = math.acos(cos)
    if angle < 1e-9:
        return [0.0, 0.0, 0.0]
    if math.pi - angle < 1e-6:  # 180°: axis from the diagonal
        axis = [math.sqrt(max(0.0, (r[i][i] + 1) / 2)) for i in range(3)]
        if axis[0] > 1e-6:
            axis[1] = math.copysign(axis[1], r[0][1])
            axis[2] = math.copysign(axis[2], r[0][2])
        elif axis[1] > 1e-6:
            axis[2] = math.copysign(axis[2], r[1][2])
        return [angle * v for v in axis]
    k = angle / (2 * math.sin(angle))
    return [k * (r[2][1] - r[1][2]), k * (r[0][2] - r[2][0]), k * (r[1][0] - r[0][1])]


def tcp_pose(q: list[float]) -> list[float]:
    t = forward(q)
    return [t[0][3], t[1][3], t[2][3], *rotvec_of([row[:3] for row in t[:3]])]


def _pose_error(pose: list[float], q: list[float]) -> list[float]:
    t = forward(q)
    r_now = [row[:3] for row in t[:3]]
    r_goal = rotation_matrix(pose[3:])
    r_err = [[sum(r_goal[i][k] * r_now[j][k] for k in range(3)) for j in range(3)] for i in range(3)]  # goal · nowᵀ
    return [pose[0] - t[0][3], pose[1] - t[1][3], pose[2] - t[2][3], *rotvec_of(r_err)]


def _solve(a: list[list[float]], b: list[float]) -> list[float]:
    n = len(b)
    m = [[*row, b[i]] for i, row in enumerate(a)]
    for col in range(n):
        pivot = max(range(col, n), key=lambda r: abs(m[r][col]))
        m[col], m[pivot] = m[pivot], m[col]
        if abs(m[col][col]) < 1e-12:
            raise ArithmeticError("singular")
        for r in range(n):
            if r != col:
                f = m[r][col] / m[col][col]
                for c in range(col, n + 1):
                    m[r][c] -= f * m[col][c]
    return [m[i][n] / m[i][i] for i in range(n)]


def inverse(pose: list[float], seed: list[float], iterations: int = 200) -> list[float] | None:
    """Damped least-squares IK from ``seed``; None when it does not converge."""
    q = list(seed)
    damping = 1e-3
    for _ in range(iterations):
        err = _pose_error(pose, q)
        if max(abs(e) for e in err) < 1e-6:
            return q
        jac = [[0.0] * 6 for _ in range(6)]
        for j in range(6):
            dq = list(q)
            dq[j] += 1e-6
            e2 = _pose_error(pose, dq)
            for i in range(6):
                jac[i][j] = (err[i] - e2[i]) / 1e-6
        jtj = [
            [sum(jac[k][i] * jac[k][j] for k in range(6)) + (damping if i == j else 0.0) for j in range(6)]
            for i in range(6)
        ]
        jte = [sum(jac[k][i] * err[k] for k in range(6)) for i in range(6)]
        try:
            step = _solve(jtj, jte)
        except ArithmeticError:
            return None
        scale = min(1.0, 0.5 / max(1e-12, max(abs(s) for s in step)))
        q = [qi + scale * si for qi, si in zip(q, step, strict=True)]
    return q if max(abs(e) for e in _pose_error(pose, q)) < 1e-5 else None
