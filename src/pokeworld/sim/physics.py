"""PokeWorld dynamics and rendering kernels (numba, vectorised over episodes).

State layout, one row per episode (float64):
``[finger_x, finger_y, finger_vx, finger_vy, object_x, object_y, object_vx, object_vy]``.
Parameter layout (float64): ``[mass, gamma, stiffness, bias_x, bias_y, gain, drift_x, drift_y]`` (the drift
acceleration of the object is read by the reference kernel only; the calibrated one never has it).

Integration is semi-implicit Euler over ``substeps`` sub-steps per control step.
Linear drag on the object (``-gamma*m*v``) and linear damping on the finger are
applied as exact exponential factors per sub-step, so a free glide decays as
``exp(-gamma*t)`` to machine precision and momentum is conserved exactly when
both are zero. Finger-object contact is a Hertzian penalty force
``k*d**1.5`` with normal damping at ``zeta`` of critical under one of two readings
(:func:`hertz_normal_force`): the *tangent* law ``c = 2 zeta sqrt(1.5 k sqrt(d) mu)`` (the
default: two-body restitution independent of k, m and impact speed, so stiffness lives in the
impact transient) or the *constant* law ``c = 2 zeta sqrt(k mu)`` (restitution falls as k rises,
a trace of stiffness in the post-contact trajectory).
Walls are mass- and stiffness-independent (their accelerations do not depend on
m or k), so no hidden parameter leaks into vision through a wall bounce.

That is the *calibrated* environment's kernel (:func:`step_kernel`, kept bit for bit so its corpora keep their
content hashes). The *reference* environment, the default (docs/design.md, "PokeWorld"), steps with
:func:`step_kernel_reference`: the authors' released simulator's dynamics. Its contact law is the *hertz* law
``k d^1.5 - 2 zeta sqrt(k mu) sqrt(d) * sep`` (not clipped: a separating contact can pull briefly), its walls are
Hertz contacts ``K d^1.5 - 2 sqrt(K) sqrt(d) v`` whose *force* is mass-independent (so a wall bounce's
acceleration carries 1/m), drag ``-gamma m v`` and finger damping enter the force sum of each explicit sub-step,
both bodies' speeds are capped per sub-step, and touch is reported in raw force units.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

# indices into the per-episode constant vector passed to the kernels
C_DT, C_NSUB, C_FMAX, C_MF, C_CF, C_RF, C_RO, C_ZETA, C_WOMEGA, C_WZETA, C_ARENA, C_DAMPING_LAW = range(12)
NUM_CONSTS = 12
DAMPING_LAWS = ("constant", "tangent", "hertz")
"""Readings of "normal damping at zeta of critical" (:func:`hertz_normal_force`); index = the kernels' code."""
TOUCH_DIM = 7
# the reference kernel's extra constants (appended: the calibrated kernel's indices are unchanged)
C_WALL_LAW, C_KWALL, C_VCAP, C_TOUCH_RAW, C_DRAG_EXPLICIT = range(12, 17)
NUM_CONSTS_REFERENCE = 17
WALL_LAWS = ("spring", "hertz")
"""Wall contact laws: the calibrated mass-independent spring, the reference's Hertz contact (index = code)."""


@njit(cache=True, inline="always")
def hertz_normal_force(d: float, sep_speed: float, k: float, mu: float, zeta: float, law: int) -> float:
    """Normal contact force magnitude for overlap ``d`` > 0 and separation speed ``sep_speed``.

    ``k d^1.5`` minus damping ``c * sep_speed``, ``mu`` the reduced mass, ``zeta`` a fraction of critical, under
    one of two readings of "normal damping at zeta of critical" (``law`` indexes :data:`DAMPING_LAWS`):

    * 0, *constant*: ``c = 2 zeta sqrt(k mu)``, critical damping of a spring of constant k (k taken as if it were
      in N/m). The damping ratio at the working overlap then grows as k falls, so a soft contact loses more of
      the impact speed than a stiff one: restitution depends on k (and weakly on the impact speed), and stiffness
      shows in the post-contact trajectory, as the paper's matched pairs (Fig. pairs (c)) show.
    * 1, *tangent*: ``c = 2 zeta sqrt(k_t mu)`` with ``k_t = 1.5 k sqrt(d)`` the tangent stiffness at the
      current overlap: zeta of critical for the local linearisation. The equation of motion in the scaled
      overlap ``d / d_max`` is then the same for every k, mu and impact speed, so restitution depends on ``zeta``
      alone and stiffness lives in the impact transient only.

    Clipped at zero: a penalty contact cannot pull.
    """
    if law == 1:
        c = 2.0 * zeta * math.sqrt(1.5 * k * math.sqrt(d) * mu)
    else:
        c = 2.0 * zeta * math.sqrt(k * mu)
    fn = k * d * math.sqrt(d) - c * sep_speed
    return fn if fn > 0.0 else 0.0


@njit(cache=True, inline="always")
def _wall_accel(x: float, v: float, r: float, arena: float, omega: float, zeta: float) -> float:
    a = 0.0
    if x < r:
        a += omega * omega * (r - x) - 2.0 * zeta * omega * v
    elif x > arena - r:
        a += -omega * omega * (x - (arena - r)) - 2.0 * zeta * omega * v
    return a


@njit(parallel=True, cache=True)
def step_kernel(state, params, actions, consts, touch):
    """Advance every episode by one control step in place; write noise-free touch statistics.

    touch[i] = [mean Fx, mean Fy, peak |F|, end Fx, end Fy, contact fraction, contact flag]
    of the reaction force on the finger over the sub-steps, forces divided by F_max.
    """
    n = state.shape[0]
    nsub = int(consts[C_NSUB])
    h = consts[C_DT] / nsub
    fmax = consts[C_FMAX]
    mf = consts[C_MF]
    cf = consts[C_CF]
    rf = consts[C_RF]
    ro = consts[C_RO]
    zeta = consts[C_ZETA]
    womega = consts[C_WOMEGA]
    wzeta = consts[C_WZETA]
    arena = consts[C_ARENA]
    law = int(consts[C_DAMPING_LAW])
    dec_f = math.exp(-cf / mf * h)
    for i in prange(n):
        fx, fy, fvx, fvy = state[i, 0], state[i, 1], state[i, 2], state[i, 3]
        ox, oy, ovx, ovy = state[i, 4], state[i, 5], state[i, 6], state[i, 7]
        m, gam, k = params[i, 0], params[i, 1], params[i, 2]
        gain = params[i, 5]
        cmdx = gain * fmax * actions[i, 0] + params[i, 3]
        cmdy = gain * fmax * actions[i, 1] + params[i, 4]
        mu = mf * m / (mf + m)
        dec_o = math.exp(-gam * h)
        sx = 0.0
        sy = 0.0
        peak = 0.0
        ncontact = 0
        cx = 0.0
        cy = 0.0
        for _ in range(nsub):
            dx = ox - fx
            dy = oy - fy
            dist = math.sqrt(dx * dx + dy * dy)
            d = rf + ro - dist
            cx = 0.0
            cy = 0.0
            if d > 0.0 and dist > 1e-12:
                nx = dx / dist
                ny = dy / dist
                sep = (ovx - fvx) * nx + (ovy - fvy) * ny
                fn = hertz_normal_force(d, sep, k, mu, zeta, law)
                cx = fn * nx
                cy = fn * ny
                ncontact += 1
                if fn > peak:
                    peak = fn
            afx = (cmdx - cx) / mf + _wall_accel(fx, fvx, rf, arena, womega, wzeta)
            afy = (cmdy - cy) / mf + _wall_accel(fy, fvy, rf, arena, womega, wzeta)
            aox = cx / m + _wall_accel(ox, ovx, ro, arena, womega, wzeta)
            aoy = cy / m + _wall_accel(oy, ovy, ro, arena, womega, wzeta)
            fvx = (fvx + afx * h) * dec_f
            fvy = (fvy + afy * h) * dec_f
            ovx = (ovx + aox * h) * dec_o
            ovy = (ovy + aoy * h) * dec_o
            fx += fvx * h
            fy += fvy * h
            ox += ovx * h
            oy += ovy * h
            sx -= cx
            sy -= cy
        state[i, 0], state[i, 1], state[i, 2], state[i, 3] = fx, fy, fvx, fvy
        state[i, 4], state[i, 5], state[i, 6], state[i, 7] = ox, oy, ovx, ovy
        touch[i, 0] = sx / nsub / fmax
        touch[i, 1] = sy / nsub / fmax
        touch[i, 2] = peak / fmax
        touch[i, 3] = -cx / fmax
        touch[i, 4] = -cy / fmax
        touch[i, 5] = ncontact / nsub
        touch[i, 6] = 1.0 if ncontact > 0 else 0.0


@njit(cache=True, inline="always")
def _draw_disk(img, x, y, r, arena, value):
    hgt, wid = img.shape
    sx = wid / arena
    sy = hgt / arena
    # pixel (row j, col c) has its centre at ((c + 0.5)/sx, (j + 0.5)/sy): row index grows with y
    cxp = x * sx - 0.5
    cyp = y * sy - 0.5
    rp = r * sx
    c0 = max(int(math.floor(cxp - rp - 1.0)), 0)
    c1 = min(int(math.ceil(cxp + rp + 1.0)), wid - 1)
    r0 = max(int(math.floor(cyp - rp - 1.0)), 0)
    r1 = min(int(math.ceil(cyp + rp + 1.0)), hgt - 1)
    for j in range(r0, r1 + 1):
        ddy = j - cyp
        for c in range(c0, c1 + 1):
            ddx = c - cxp
            cov = rp - math.sqrt(ddx * ddx + ddy * ddy) + 0.5
            if cov <= 0.0:
                continue
            if cov > 1.0:
                cov = 1.0
            v = np.uint8(int(value * cov + 0.5))
            if v > img[j, c]:
                img[j, c] = v


@njit(parallel=True, cache=True)
def render_kernel(state, out, rf, ro, arena, object_value, finger_value):
    """Anti-aliased grayscale renders of every episode into ``out`` (N, H, W) uint8.

    Object: filled disk at ``object_value``; finger: filled disk at ``finger_value``
    (max-blended), background 0. Coverage is approximated by the signed distance
    to the disk edge clamped to one pixel, which is smooth in sub-pixel motion.
    Depends on positions only, so renders cannot reveal any hidden parameter.
    """
    for i in prange(out.shape[0]):
        img = out[i]
        img[:, :] = 0
        _draw_disk(img, state[i, 4], state[i, 5], ro, arena, object_value)
        _draw_disk(img, state[i, 0], state[i, 1], rf, arena, finger_value)


@njit(cache=True, inline="always")
def hertz_damped_force(d: float, sep_speed: float, k: float, mu: float, zeta: float) -> float:
    """The reference's contact law: ``k d^1.5 - 2 zeta sqrt(k mu) sqrt(d) * sep_speed``, not clipped.

    Damping grows with sqrt(d) like the spring's tangent stiffness, but with the constant ``sqrt(k mu)`` in front
    the damping ratio at the working overlap falls as k rises: restitution rises with k (0.74 / 0.77 / 0.79 at k
    500 / 1732 / 6000, head-on at 1.3 with m 1.22), a post-contact trace of stiffness."""
    sd = math.sqrt(d)
    return k * d * sd - 2.0 * zeta * math.sqrt(k * mu) * sd * sep_speed


@njit(cache=True, inline="always")
def _hertz_wall_force(x: float, v: float, r: float, arena: float, kwall: float) -> float:
    """Force (not acceleration) of the two walls of one axis on a disk of radius ``r``: Hertz, critically scaled
    damping ``2 sqrt(K) sqrt(d) v``; the same for every mass, so the bounce's acceleration carries 1/m."""
    f = 0.0
    low = r - x
    if low > 0.0:
        sd = math.sqrt(low)
        f += kwall * low * sd - 2.0 * math.sqrt(kwall) * v * sd
    high = x - (arena - r)
    if high > 0.0:
        sd = math.sqrt(high)
        f -= kwall * high * sd + 2.0 * math.sqrt(kwall) * v * sd
    return f


@njit(cache=True, inline="always")
def _wall_force_on(x: float, v: float, r: float, arena: float, mass: float, consts) -> float:
    if consts[C_WALL_LAW] == 1.0:
        return _hertz_wall_force(x, v, r, arena, consts[C_KWALL])
    return mass * _wall_accel(x, v, r, arena, consts[C_WOMEGA], consts[C_WZETA])


@njit(cache=True, inline="always")
def _contact(d: float, sep: float, k: float, mu: float, zeta: float, law: int) -> float:
    if law == 2:
        return hertz_damped_force(d, sep, k, mu, zeta)
    return hertz_normal_force(d, sep, k, mu, zeta, law)


@njit(cache=True, inline="always")
def _cap(vx: float, vy: float, cap: float):
    if cap > 0.0:
        sp = math.sqrt(vx * vx + vy * vy)
        if sp > cap:
            return vx * cap / sp, vy * cap / sp
    return vx, vy


@njit(parallel=True, cache=True)
def step_kernel_reference(state, params, actions, consts, touch):
    """:func:`step_kernel` under the reference environment's laws (module docstring); the same state, parameter
    and touch layouts. Per sub-step: forces from the current state (contact, drag, walls, command, damping), then
    velocities, the speed cap, positions. Touch forces are raw (``consts[C_TOUCH_RAW]``) or divided by F_max."""
    n = state.shape[0]
    nsub = int(consts[C_NSUB])
    h = consts[C_DT] / nsub
    fmax, mf, cf = consts[C_FMAX], consts[C_MF], consts[C_CF]
    rf, ro, zeta, arena = consts[C_RF], consts[C_RO], consts[C_ZETA], consts[C_ARENA]
    law = int(consts[C_DAMPING_LAW])
    vcap = consts[C_VCAP]
    explicit = consts[C_DRAG_EXPLICIT] == 1.0
    scale = 1.0 if consts[C_TOUCH_RAW] == 1.0 else 1.0 / fmax
    dec_f = 1.0 if explicit else math.exp(-cf / mf * h)
    for i in prange(n):
        fx, fy, fvx, fvy = state[i, 0], state[i, 1], state[i, 2], state[i, 3]
        ox, oy, ovx, ovy = state[i, 4], state[i, 5], state[i, 6], state[i, 7]
        m, gam, k = params[i, 0], params[i, 1], params[i, 2]
        cmdx = params[i, 5] * fmax * actions[i, 0] + params[i, 3]
        cmdy = params[i, 5] * fmax * actions[i, 1] + params[i, 4]
        drift_x, drift_y = m * params[i, 6], m * params[i, 7]  # the force of the drift acceleration (0: none)
        mu = mf * m / (mf + m)
        dec_o = 1.0 if explicit else math.exp(-gam * h)
        sx, sy, peak, ncontact, cx, cy = 0.0, 0.0, 0.0, 0, 0.0, 0.0
        for _ in range(nsub):
            dx, dy = ox - fx, oy - fy
            dist = math.sqrt(dx * dx + dy * dy)
            d = rf + ro - dist
            cx, cy = 0.0, 0.0
            if d > 0.0 and dist > 1e-12:
                nx, ny = dx / dist, dy / dist
                fn = _contact(d, (ovx - fvx) * nx + (ovy - fvy) * ny, k, mu, zeta, law)
                cx, cy = fn * nx, fn * ny
                if abs(fn) > 1e-6:
                    ncontact += 1
                peak = max(peak, abs(fn))
            ffx = cmdx - cx + _wall_force_on(fx, fvx, rf, arena, mf, consts)
            ffy = cmdy - cy + _wall_force_on(fy, fvy, rf, arena, mf, consts)
            fox = cx + _wall_force_on(ox, ovx, ro, arena, m, consts) + drift_x
            foy = cy + _wall_force_on(oy, ovy, ro, arena, m, consts) + drift_y
            if explicit:
                ffx -= cf * fvx
                ffy -= cf * fvy
                fox -= gam * m * ovx
                foy -= gam * m * ovy
            fvx, fvy = _cap((fvx + ffx / mf * h) * dec_f, (fvy + ffy / mf * h) * dec_f, vcap)
            ovx, ovy = _cap((ovx + fox / m * h) * dec_o, (ovy + foy / m * h) * dec_o, vcap)
            fx += fvx * h
            fy += fvy * h
            ox += ovx * h
            oy += ovy * h
            sx -= cx
            sy -= cy
        state[i, 0], state[i, 1], state[i, 2], state[i, 3] = fx, fy, fvx, fvy
        state[i, 4], state[i, 5], state[i, 6], state[i, 7] = ox, oy, ovx, ovy
        touch[i, 0] = sx / nsub * scale
        touch[i, 1] = sy / nsub * scale
        touch[i, 2] = peak * scale
        touch[i, 3] = -cx * scale
        touch[i, 4] = -cy * scale
        touch[i, 5] = ncontact / nsub
        touch[i, 6] = 1.0 if ncontact > 0 else 0.0
