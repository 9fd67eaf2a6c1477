"""The steps of `fu2018` and `elastic`, written once: their force system, friction laws and stepping,
their constants' layouts and the solver memory as they hold it.

Each function here is plain Python on floats and is the one source of its law. `load("compiled")`
imports numba and compiles the functions marked `_compiled` (on first use, so that `import prsm_sim`
does not pull numba in; compiled code is cached on disk, a fresh install compiles once);
`load("reference")` gives the same functions uncompiled, bound to one another (never to a compiled
twin), so the reference run is this source run by the Python interpreter. tests/test_kernels.py holds
the two runs together (1e-12; bit-identical where seen); the models' physics tests (closed forms,
conservation, the papers' figures) check the source itself.

Constants travel as float arrays whose layout is a NamedTuple per model (`Fu2018Constants`,
`ElasticConstants`, and `FlankConstants` for the geometry of one flank pair): the model builds the
array from the NamedTuple, the kernels read ``K[FU.mu]`` with ``FU`` the NamedTuple of indices, so
both sides derive from one list of names. They live in this file because numba freezes globals into
its on-disk cache, which it keys on this file only. Not globals of the values: a value frozen into
the cache would outlive a parameter change.

Conventions: the `Forces` of an evaluation is a tuple of 29 floats in `Forces` field order; the
solver memory is 6 floats (j00, j01, j10, j11, sign, age) with sign 0 meaning empty (the reference
path's ``()``, `kernel_memory`); flank signs are ±1.0.

Few, large functions with one signature each keep the first compile (a fresh clone, no cache)
short: numba compiles per function and signature.
"""

from __future__ import annotations

import math
import sys
import types
from enum import IntEnum
from typing import NamedTuple

from prsm_sim.errors import ParamError
from prsm_sim.stepping.ledger import ENERGY_GUARD_MIN_FLOW_J, ENERGY_GUARD_REL, ledger_step

KERNELS = ("compiled", "reference")


class ScrewRollerLaw(IntEnum):
    """The screw–roller friction law (`friction.screw_roller_law`), as the step's constants carry it."""

    VISCOUS = 0  # f = −c N_T v_s: the Jones 2016 limit
    COULOMB = 1  # f = −μ N v_s/√(|v_s|² + ε²): regularised Coulomb

    @classmethod
    def from_name(cls, name: str) -> ScrewRollerLaw:
        return cls[name.upper()]


class Fu2018Constants(NamedTuple):
    """The `fu2018` step's constants (`Fu2018.constants`); the reference path reads them by name too."""

    screw_roller_law: float  # a `ScrewRollerLaw` (its integer value in the float array)
    mu: float  # μ_SR
    mu_n: float  # μ of the nut contact's sliding (0 when it rolls, the standard design)
    eps_v2: float  # ε², m²/s²: the Coulomb regularisation speed squared
    eps_w2: float  # the same as a carrier speed at the roller radius, squared
    c_nt: float  # viscous coefficient × N_T
    mu_pin_r: float  # μ_pin r_pin
    k_drag: float  # Couette drag coefficient of both ring gear–carrier gaps, N·m·s
    mu_rr_r: float  # μ_NR r_R (rolling resistance)
    nr: float  # N_R
    a: float  # carrier radius, m
    r_g: float  # the roller gear's pitch radius a/(g − 1), m
    mp: float  # moved mass × L/2π
    i_s: float  # screw inertia
    i_c: float  # carrier inertia
    mr_p: float  # roller mass × L/2π
    mr_kmig: float  # roller mass × the migration lead P (n − g)/2π
    mr_a: float  # roller mass × a
    j_spin: float  # the carrier-mode inertia of the spin equation
    tan_gear: float  # tan of the gear pressure angle
    g: float  # gear ratio
    s_1g: float  # sign of (1 − g)
    span: float  # pin/gear span along the roller, m
    zbar: float  # axial position of the thread load's resultant, m
    nut_slides: float  # 1.0 off the standard design (g ≠ r_N/r_R)
    h: float  # the step, s
    h_min: float  # the smallest error-controlled sub-step
    h_zone: float  # the smallest sub-step for slow slip alone
    slip_tol: float  # step-doubling tolerance on the slip, m/s
    eps_v: float  # ε, m/s
    kss: float  # mass matrix (ω_S, ω_C): the stored energy
    ksc: float
    kcc: float
    jacobian_refresh: float  # steps a frozen Jacobian is kept
    slip_zone: float  # slow slip: within this many ε of zero
    balance_tol: float  # a step's own energy balance: relative tolerance
    balance_floor: float  # ... and absolute, J
    p: float  # lead per radian, m
    drag_on: float  # 1.0: the load-independent losses below act (`DragParams.enabled`)
    seal_torque: float  # seal/wiper torque T_s on the screw, N·m
    eps_ws: float  # the Coulomb regularisation ε as a screw speed at the seal radius (ε / r_S), rad/s
    film_nt: float  # film shear traction coefficient × N_T (all contacts of one roller), N·s/m
    idle_axial: float  # axial force of the idle-flank contacts per roller, 2 P_i / N_R, N
    hold_forward: float  # the screw torque the load-independent drag holds at rest (`Fu2018.drag_holds_nm`), N·m
    hold_backward: float  # ... and in the other direction (its magnitude), N·m


class FlankConstants(NamedTuple):
    """The contact geometry of one flank pair (`fu2018`), for the scalar step: G (row major), n_S,
    P_S (x, y), P_S − axis (x, y), n_N, P_N − axis (x, y), H (row major)."""

    g00: float
    g01: float
    g10: float
    g11: float
    g20: float
    g21: float
    nsx: float
    nsy: float
    nsz: float
    psx: float
    psy: float
    rsx: float
    rsy: float
    nnx: float
    nny: float
    nnz: float
    rnx: float
    rny: float
    h00: float
    h01: float
    h10: float
    h11: float
    h20: float
    h21: float


class ElasticConstants(NamedTuple):
    """The `elastic` sub-step loop's constants (`ElasticModel.constants`)."""

    p: float  # lead per radian, m
    m: float  # moved mass, kg
    mu: float  # reduced mass of the two sides, kg
    zeta: float  # contact damping ratio
    substeps: float  # sub-steps per step
    hs: float  # the sub-step, s
    breakaway: float  # 1.0: Stribeck breakaway on
    eta_sf: float  # static sliding efficiencies (forward, backward)
    eta_sb: float
    w_stick: float  # stick window, rad/s
    czs: float  # c_zS
    sin_beta: float  # sin β
    mu_c: float  # running μ
    eta_rf: float  # running sliding efficiencies (forward, backward)
    eta_rb: float
    d_mu: float  # μ_s − μ_c
    p_sb_vs: float  # ω_S → v/v_s
    clearance: float  # axial clearance, m
    preload: float  # preload, N
    law_a: float  # δ = a F^(2/3) + b F
    law_b: float
    ea: float  # E A of the screw section, N
    x_bearing: float  # fixed bearing position, m
    c_housing: float  # housing compliance, m/N
    d0: float  # preload approach, m
    v0: float  # preload energy, J
    m00: float  # the core's mass matrix
    m01: float
    m11: float
    impact_tol: float
    impact_floor: float
    impact_iter: float
    c_side: float  # compliance of the flank set(s) at the static rating (the stiffest the nut gets), m/N
    wh_refine: float  # ω h above which a step's sub-steps are halved (`_refinement`)
    # reciprocals the sub-step multiplies by where it would divide (two to eight divisions a sub-step fewer)
    inv_ea: float  # 1/(E A), 1/N
    inv_m: float  # 1/m, 1/kg


FU = Fu2018Constants(*range(len(Fu2018Constants._fields)))  # the kernels' indices into a constants array
FL = FlankConstants(*range(len(FlankConstants._fields)))
EL = ElasticConstants(*range(len(ElasticConstants._fields)))
NO_MEMORY = (0.0,) * 6  # the solver memory when there is none
ROOT_STEP_TOL = 1e-6  # relative Halley step at which `_power_root` stops (its error is then below rounding)
_NAN29 = (math.nan,) * 29  # a `Forces` tuple that holds nothing


def kernel_memory(mem: tuple) -> tuple:
    """The solver memory as the compiled kernel holds it: 6 floats, sign 0 for none."""
    return tuple(map(float, mem)) if len(mem) == 6 else NO_MEMORY  # floats: one compiled specialisation


def memory_from_kernel(mem: tuple) -> tuple:
    """The kernel's solver memory as the reference path holds it (``()`` for none)."""
    return mem if mem[4] != 0.0 else ()


def check_kernel(kernel) -> None:
    """ParamError (one line: field, value, allowed values) unless `kernel` is one of KERNELS."""
    if kernel not in KERNELS:
        raise ParamError(f"kernel = {kernel!r}: allowed values are {', '.join(map(repr, KERNELS))}")


_COMPILED: list[str] = []  # the functions `load` compiles, in definition order
_INLINED: set[str] = set()  # ... of which numba inlines these into their callers (small helpers on the hot path)


def specialised(fn, *args):
    """`fn` as the per-step path calls it: for a numba dispatcher the compiled entry point of the specialisation
    that `args` (an example call's arguments, already compiled) select, else `fn` itself.

    A dispatcher finds the specialisation anew on every call by typing each argument (a third of a microsecond
    for `kernels.step`'s ten, a tuple among them); the per-step path passes arguments of fixed types (floats
    checked by its callers, the kernel's own memory and constants), so the entry point found once serves every
    step, with the same machine code and results. An argument of another type is converted by the entry point
    as the dispatcher's would be, or refused (TypeError).
    """
    overloads = getattr(fn, "overloads", None)
    if overloads is None:  # the reference kernel: a plain function
        return fn
    from numba import typeof  # a compiled kernel is loaded: numba is

    compiled = overloads.get(tuple(typeof(a) for a in args))
    return fn if compiled is None else compiled.entry_point


def _compiled(fn):
    """Mark a function for numba (compiled by `load`, which replaces it in this module by its dispatcher)."""
    _COMPILED.append(fn.__name__)
    return fn


def _inlined(fn):
    """`_compiled`, and inlined by numba into its callers: a helper that splits a step into readable parts
    without the cost of a call on the hot path."""
    _INLINED.add(fn.__name__)
    return _compiled(fn)


# The energy ledger (`stepping.ledger`, every model's) runs compiled in `step_record`, from its one source. Its
# guard's constants are named here too: the reference functions run on a copy of this module's globals. numba keys
# a function's disk cache on its own file only, and a cached `step_record` would outlive a change of the ledger's:
# so the ledger's fingerprint is written here (a change of it changes this file, which renews the cache), and
# `load` compiles `step_record` without its cache when the ledger no longer matches it (tests/test_kernels.py
# keeps the two equal).
_inlined(ledger_step)
LEDGER_FINGERPRINT = "96a7aea5f770c45680c73cb9401a08878f279c780a275436f579d72ca4a26f36"


def ledger_fingerprint() -> str:
    """SHA-256 of `ledger_step`'s source and the guard's constants (what `step_record` compiles in)."""
    import hashlib
    import inspect

    text = inspect.getsource(getattr(ledger_step, "py_func", ledger_step))
    return hashlib.sha256(f"{text}{ENERGY_GUARD_REL!r}{ENERGY_GUARD_MIN_FLOW_J!r}".encode()).hexdigest()


_REFERENCE: list[types.SimpleNamespace] = []  # the uncompiled functions, bound to one another (made once)


def _reference() -> types.SimpleNamespace:
    """The functions of this module uncompiled, each calling the others uncompiled: a copy of the module's
    globals in which every `_compiled` name is its plain function, rebound to that copy."""
    if not _REFERENCE:
        g = dict(globals())
        for name in _COMPILED:
            fn = getattr(g[name], "py_func", g[name])
            g[name] = types.FunctionType(fn.__code__, g, fn.__name__, fn.__defaults__, fn.__closure__)
        _REFERENCE.append(types.SimpleNamespace(**{name: g[name] for name in _COMPILED}))
    return _REFERENCE[0]


def load(kernel: str):
    """The functions of this module: compiled (numba; this module itself) for ``kernel="compiled"``, or
    uncompiled for ``"reference"`` (the same source under the Python interpreter)."""
    check_kernel(kernel)
    if kernel == "reference":
        return _reference()
    g = globals()
    if not hasattr(g[_COMPILED[-1]], "py_func"):
        from numba import njit  # here, on first use: `import prsm_sim` stays light

        # every dispatcher made before any is published (one dict update): a caller never sees a mix
        uncached = set() if ledger_fingerprint() == LEDGER_FINGERPRINT else {"step_record"}
        # without numba's reference-counted runtime (`_nrt=False`, numba's own switch; numba is pinned to one
        # minor version): the kernels allocate nothing, and with the runtime every call of a kernel that takes an
        # array (the constants E, K, S) counts each array in and out with atomic instructions, about half of
        # `elastic`'s batch time (perf: numba's NRT_incref/NRT_decref). The arithmetic is the same.
        runtime: dict = {"_nrt": False}  # (a keyword numba's type stubs do not list)
        g.update({name: njit(cache=name not in uncached, inline="always" if name in _INLINED else "never", **runtime)(
            getattr(g[name], "py_func", g[name])) for name in _COMPILED})
    return sys.modules[__name__]


# -- fu2018 -------------------------------------------------------------------------------------
@_inlined
def _contact_laws(w_s, w_c, stick_on, st0, st1, st2, row, K):
    """The contacts' friction laws: the sliding velocities v_s = G u (screw), v_n = H u (nut), the directions
    e = n + friction per unit normal force of the screw and nut contacts and the screw friction f₀ that does not
    scale with the normal force (the viscous law), per roller. At rest (`stick_on`) the screw's static friction
    per unit normal force (st0, st1, st2) as `_stick` solved it. Returns (v_s, e_S, f₀, v_n, e_N), 15 floats.

    Screw–roller (`ScrewRollerLaw`): COULOMB f = −μ N v_s/√(|v_s|² + ε²), VISCOUS f = −c N_T v_s (Jones
    2016's limit, load-independent). Nut–roller sliding (off the standard design only): regularised Coulomb.
    With the drag on (`DragParams`), while sliding, two load-independent terms join f₀: the film's Newtonian
    shear traction −c_f N_T v_s (c_f = ρ ν A/h per contact) and the idle flanks' contact force N_i = 2 P_i/(N_R
    |n_z|) through the Coulomb law, −μ N_i v_s/√(|v_s|² + ε²) (its direction taken as the loaded flank's slip).
    """
    g00, g01, g10, g11, g20, g21 = row[FL.g00], row[FL.g01], row[FL.g10], row[FL.g11], row[FL.g20], row[FL.g21]
    nsx, nsy, nsz = row[FL.nsx], row[FL.nsy], row[FL.nsz]
    nnx, nny, nnz = row[FL.nnx], row[FL.nny], row[FL.nnz]
    h00, h01, h10, h11, h20, h21 = row[FL.h00], row[FL.h01], row[FL.h10], row[FL.h11], row[FL.h20], row[FL.h21]
    mu, mu_n, eps_v2, c_nt = K[FU.mu], K[FU.mu_n], K[FU.eps_v2], K[FU.c_nt]
    vx = g00 * w_s + g01 * w_c
    vy = g10 * w_s + g11 * w_c
    vz = g20 * w_s + g21 * w_c
    f0x = f0y = f0z = 0.0
    if stick_on:
        esx, esy, esz = nsx + st0, nsy + st1, nsz + st2
    elif int(K[FU.screw_roller_law]) == ScrewRollerLaw.COULOMB:
        k = mu / math.sqrt(vx * vx + vy * vy + vz * vz + eps_v2)
        esx, esy, esz = nsx - k * vx, nsy - k * vy, nsz - k * vz
    else:
        esx, esy, esz = nsx, nsy, nsz
        f0x, f0y, f0z = -c_nt * vx, -c_nt * vy, -c_nt * vz
    if K[FU.drag_on] != 0.0 and not stick_on:
        # load-independent: the film's shear traction, and the idle flanks' contact force through the Coulomb law
        kd = K[FU.film_nt]
        if int(K[FU.screw_roller_law]) == ScrewRollerLaw.COULOMB:
            kd += mu * (K[FU.idle_axial] / abs(nsz)) / math.sqrt(vx * vx + vy * vy + vz * vz + eps_v2)
        f0x, f0y, f0z = f0x - kd * vx, f0y - kd * vy, f0z - kd * vz
    if K[FU.nut_slides] != 0.0:
        wx = h00 * w_s + h01 * w_c
        wy = h10 * w_s + h11 * w_c
        wz = h20 * w_s + h21 * w_c
    else:
        wx = wy = wz = 0.0
    if mu_n != 0.0 and not stick_on:
        kn = mu_n / math.sqrt(wx * wx + wy * wy + wz * wz + eps_v2)
        enx, eny, enz = nnx - kn * wx, nny - kn * wy, nnz - kn * wz
    else:
        enx, eny, enz = nnx, nny, nnz
    return vx, vy, vz, esx, esy, esz, f0x, f0y, f0z, wx, wy, wz, enx, eny, enz


@_compiled
def solve(w_s, w_c, tau, load, sign, pin_abs, gear_sign, forces, stick_on, st0, st1, st2, st3, st4, K, S):
    """Equations 1–7 (`fu2018` module doc) eliminated by hand to a 2×2 system in (ω̇_S, ω̇_C); 29 floats
    (`Forces` order). Without `forces` only the accelerations are meaningful (the rest is NaN).

    Nut (2) and screw (1) give N_N and N_S linearly in ω̇_S; the carriers (7) give F_pt, the roller
    tangential balance (5) F_gt; roller axial (3) and spin (6) are then two equations in the two
    accelerations; the radial balance (4) gives F_pr, the tilting balance the two pin reactions. `stick_on`:
    at rest (u = 0) with the static friction `_stick` solved (st0..st2 per unit N_S, st3 the share σ of the
    pin and rolling moments, st4 = N_S); the accelerations are then zero.
    """
    row = S[0] if sign > 0.0 else S[1]
    nsx, nsy, nsz = row[FL.nsx], row[FL.nsy], row[FL.nsz]
    psx, psy, rsx, rsy = row[FL.psx], row[FL.psy], row[FL.rsx], row[FL.rsy]
    nnx, nny, nnz, rnx, rny = row[FL.nnx], row[FL.nny], row[FL.nnz], row[FL.rnx], row[FL.rny]
    eps_w2 = K[FU.eps_w2]
    mu_pin_r, k_drag, mu_rr_r, nr, a, r_g = K[FU.mu_pin_r], K[FU.k_drag], K[FU.mu_rr_r], K[FU.nr], K[FU.a], K[FU.r_g]
    mp, i_s, i_c, mr_p, mr_kmig, mr_a = K[FU.mp], K[FU.i_s], K[FU.i_c], K[FU.mr_p], K[FU.mr_kmig], K[FU.mr_a]
    j_spin, tan_gear, g, s_1g, span, zbar = K[FU.j_spin], K[FU.tan_gear], K[FU.g], K[FU.s_1g], K[FU.span], K[FU.zbar]
    (vx, vy, vz, esx, esy, esz, f0x, f0y, f0z, wx, wy, wz, enx, eny, enz) = _contact_laws(w_s, w_c, stick_on, st0, st1,
                                                                                       st2, row, K)
    spin_n = rnx * eny - rny * enx
    mom_s = psx * esy - psy * esx
    mom_f0 = psx * f0y - psy * f0x
    spin_s = rsx * esy - rsy * esx
    spin_f0 = rsx * f0y - rsy * f0x
    s_c = w_c / math.sqrt(w_c * w_c + eps_w2) if not stick_on else st3
    m_pin = mu_pin_r * pin_abs * s_c
    m_drag = -k_drag * w_c
    mu_rr = mu_rr_r * s_c * s_1g
    alpha_n = mp / (nr * enz)
    beta_n = load / (nr * enz)
    rhs7 = -nr * m_pin + m_drag
    m_seal = 0.0
    if K[FU.drag_on] != 0.0 and not stick_on:  # the seals on the screw: regularised Coulomb (held at rest elsewhere)
        m_seal = -K[FU.seal_torque] * w_s / math.sqrt(w_s * w_s + K[FU.eps_ws] * K[FU.eps_ws])
        tau = tau + m_seal
    if stick_on:  # the static state `_stick` solved: no acceleration, its own N_S (mom_s may be 0)
        acc_s = acc_c = 0.0
        if not forces:
            return (acc_s, acc_c) + _NAN29[2:]
        n_s = st4
    else:
        alpha_s = -i_s / (nr * mom_s)
        beta_s = (tau - nr * mom_f0) / (nr * mom_s)
        a11 = -mr_p - esz * alpha_s - enz * alpha_n
        a12 = mr_kmig
        b1 = f0z + esz * beta_s + enz * beta_n
        cs = r_g * esy - spin_s
        cn = r_g * eny - (spin_n - mu_rr)
        a21 = cs * alpha_s + cn * alpha_n
        a22 = j_spin
        b2 = spin_f0 + m_pin - r_g * f0y - r_g * rhs7 / (nr * a) - cs * beta_s - cn * beta_n
        det = a11 * a22 - a12 * a21
        acc_s = (b1 * a22 - a12 * b2) / det
        acc_c = (a11 * b2 - a21 * b1) / det
        if not forces:
            return (acc_s, acc_c) + _NAN29[2:]
        n_s = alpha_s * acc_s + beta_s
    n_n = alpha_n * acc_s + beta_n
    f_pt = (rhs7 - i_c * acc_c) / (nr * a)
    f_gt = mr_a * acc_c - esy * n_s - eny * n_n - f_pt - f0y
    tan_g = tan_gear * gear_sign
    f_pr = -mr_a * w_c * w_c - f0x - esx * n_s - enx * n_n + tan_g * f_gt
    fx, fy, fz = n_s * (esx - nsx) + f0x, n_s * (esy - nsy) + f0y, n_s * (esz - nsz) + f0z
    fnx, fny, fnz = n_n * (enx - nnx), n_n * (eny - nny), n_n * (enz - nnz)
    m_rr = -n_n * mu_rr
    sx, sy, sz = n_s * esx + f0x, n_s * esy + f0y, n_s * esz + f0z
    nx_, ny_, nz_ = n_n * enx, n_n * eny, n_n * enz
    m_x = rsy * sz - zbar * sy + rny * nz_ - zbar * ny_
    m_y = zbar * sx - rsx * sz + zbar * nx_ - rnx * nz_
    dx, dy = -2.0 * m_y / span, 2.0 * m_x / span
    diss = nr * (-(fx * vx + fy * vy + fz * vz) - (fnx * wx + fny * wy + fnz * wz) - m_pin * (-g * w_c)
                 - m_rr * ((1.0 - g) * w_c)) - m_drag * w_c - m_seal * w_s
    return (acc_s, acc_c, diss, n_s, n_n, fx, fy, fz, vx, vy, vz, m_rr, f_gt, -tan_g * f_gt, f_pr, f_pt,
            m_pin, fnx, fny, fnz, math.sqrt(wx * wx + wy * wy + wz * wz), m_y,
            0.5 * (f_pr + dx), 0.5 * (f_pt + dy), 0.5 * (f_pr - dx), 0.5 * (f_pt - dy),
            m_drag, nr * n_n * enz, sign)


@_compiled
def solve_forces(w_s, w_c, tau, load, sign, pin_abs, gear_sign, K, S):
    """The force system while sliding (`Fu2018.solve_forces`): `solve` with the flank pair `sign`, or the other
    pair if a normal force comes out in tension (the pair that carries the load compressively)."""
    f = solve(w_s, w_c, tau, load, sign, pin_abs, gear_sign, True, False, 0.0, 0.0, 0.0, 0.0, 0.0, K, S)
    if f[3] < 0.0 or f[4] < 0.0:
        g = solve(w_s, w_c, tau, load, -sign, pin_abs, gear_sign, True, False, 0.0, 0.0, 0.0, 0.0, 0.0, K, S)
        if g[3] >= 0.0 and g[4] >= 0.0:
            f = g
    return f


@_compiled
def _pin_sum(f):
    """`Forces.pin_force_sum_n`."""
    return math.sqrt(f[22] * f[22] + f[23] * f[23]) + math.sqrt(f[24] * f[24] + f[25] * f[25])


@_compiled
def _stick(tau, load, sign, pin_abs, gear_sign, K, S):
    """The static state at rest for one pass (`Fu2018.stick_forces` describes it): (found, forces, r)."""
    mu, mu_pin_r, mu_rr_r, nr, a, r_g, s_1g = K[FU.mu], K[FU.mu_pin_r], K[FU.mu_rr_r], K[FU.nr], K[FU.a], K[FU.r_g], \
        K[FU.s_1g]
    for sg in (sign, -sign):
        row = S[0] if sg > 0.0 else S[1]
        g00, g01, g10, g11, g20, g21 = row[FL.g00], row[FL.g01], row[FL.g10], row[FL.g11], row[FL.g20], row[FL.g21]
        nsx, nsy, nsz = row[FL.nsx], row[FL.nsy], row[FL.nsz]
        psx, psy, rsx, rsy = row[FL.psx], row[FL.psy], row[FL.rsx], row[FL.rsy]
        nnx, nny, nnz, rnx, rny = row[FL.nnx], row[FL.nny], row[FL.nnz], row[FL.rnx], row[FL.rny]
        n_n = load / (nr * nnz)
        spin_n = rnx * nny - rny * nnx
        k = r_g - rsx
        a00, a01, a02 = nr * (psx * nsy - psy * nsx), nr * (psx * g10 - psy * g00), nr * (psx * g11 - psy * g01)
        a10, a11, a12 = nsz, g20, g21
        a20, a21, a22 = k * nsy + rsy * nsx, k * g10 + rsy * g00, k * g11 + rsy * g01
        # `_solve3` (Cramer) for the two right-hand sides
        c00, c01, c02 = a11 * a22 - a12 * a21, a12 * a20 - a10 * a22, a10 * a21 - a11 * a20
        det = a00 * c00 + a01 * c01 + a02 * c02
        if det == 0.0 or not math.isfinite(det):
            continue
        b0, b1, b2 = tau, -nnz * n_n, -(r_g * nny - spin_n) * n_n
        x00 = (b0 * c00 + b1 * (a02 * a21 - a01 * a22) + b2 * (a01 * a12 - a02 * a11)) / det
        x01 = (b0 * c01 + b1 * (a00 * a22 - a02 * a20) + b2 * (a02 * a10 - a00 * a12)) / det
        x02 = (b0 * c02 + b1 * (a01 * a20 - a00 * a21) + b2 * (a00 * a11 - a01 * a10)) / det
        b0, b1, b2 = 0.0, 0.0, mu_pin_r * pin_abs * (1.0 + r_g / a) - mu_rr_r * s_1g * n_n
        x10 = (b0 * c00 + b1 * (a02 * a21 - a01 * a22) + b2 * (a01 * a12 - a02 * a11)) / det
        x11 = (b0 * c01 + b1 * (a00 * a22 - a02 * a20) + b2 * (a02 * a10 - a00 * a12)) / det
        x12 = (b0 * c02 + b1 * (a01 * a20 - a00 * a21) + b2 * (a00 * a11 - a01 * a10)) / det
        q00, q01, q02 = g00 * x01 + g01 * x02, g10 * x01 + g11 * x02, g20 * x01 + g21 * x02
        q10, q11_, q12 = g00 * x11 + g01 * x12, g10 * x11 + g11 * x12, g20 * x11 + g21 * x12
        mu2 = mu * mu
        d01 = q00 * q10 + q01 * q11_ + q02 * q12
        q11 = q10 * q10 + q11_ * q11_ + q12 * q12
        qa = q11 - mu2 * x10 * x10
        qb = 2.0 * (d01 - mu2 * x00 * x10)
        # the candidates in order: the ends, the middle, then each stationary point that exists (NaN: none)
        c_q = max(-1.0, min(1.0, -d01 / q11)) if q11 > 0.0 else math.nan
        c_a = max(-1.0, min(1.0, -qb / (2.0 * qa))) if qa > 0.0 else math.nan
        best = math.inf
        sig = n_s = qq0 = qq1 = qq2 = 0.0
        for s_ in (-1.0, 1.0, 0.0, c_q, c_a):
            if math.isnan(s_):
                continue
            n_ = x00 + s_ * x10
            if n_ > 0.0:
                t0, t1, t2 = q00 + s_ * q10, q01 + s_ * q11_, q02 + s_ * q12
                r_ = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2) / n_  # (|q|/N_S)²: N_S² may underflow
                r_ *= r_
                if r_ < best:
                    best, sig, n_s, qq0, qq1, qq2 = r_, s_, n_, t0, t1, t2
        if best == math.inf:
            continue
        f = solve(0.0, 0.0, tau, load, sg, pin_abs, gear_sign, True, True, qq0 / n_s, qq1 / n_s, qq2 / n_s, sig,
                  n_s, K, S)
        if f[3] >= 0.0 and f[4] >= 0.0 and math.isfinite(f[3]):
            mag = math.sqrt(qq0 * qq0 + qq1 * qq1 + qq2 * qq2) / n_s
            return True, f, (mag / mu if mu > 0 else (0.0 if mag == 0.0 else math.inf))
    return False, _NAN29, math.inf


@_compiled
def stick_forces(tau, load, sign, pin_abs, gear_sign, K, S):
    """The static state at rest (`Fu2018.stick_forces`): (found, forces, r), `_stick` solved again with the pin
    forces it sets when they differ from `pin_abs` by more than 1 %."""
    ok, f, r = _stick(tau, load, sign, pin_abs, gear_sign, K, S)
    if ok:
        ps = _pin_sum(f)
        if abs(ps - pin_abs) > 0.01 * ps:
            ok, f, r = _stick(tau, load, f[28], ps, gear_sign, K, S)
    return ok, f, r


@_compiled
def rosenbrock(ws, wc, flank_sign, pin_abs, gear_force, mem, tau, load, h, K, S):
    """One ROS2 step of length h (Verwer et al. 1999, γ = 1 + 1/√2, L-stable) with a finite-difference
    Jacobian frozen for `jacobian_refresh` steps while the flank pair holds: (ω_S, ω_C, end forces, start forces,
    memory). The pin force sum is refreshed when it moved by more than 1 %."""
    gsign = 1.0 if gear_force >= 0.0 else -1.0
    f0 = solve_forces(ws, wc, tau, load, flank_sign, pin_abs, gsign, K, S)
    ps = _pin_sum(f0)
    if abs(ps - pin_abs) > 1e-2 * ps:
        pin_abs = ps
        f0 = solve_forces(ws, wc, tau, load, f0[28], pin_abs, gsign, K, S)
    sign = f0[28]
    fs, fc = f0[0], f0[1]
    if mem[4] != 0.0 and mem[4] == sign and mem[5] < K[FU.jacobian_refresh]:
        j00, j01, j10, j11 = mem[0], mem[1], mem[2], mem[3]
        age = mem[5] + 1
    else:
        ds = 1e-6 * max(1.0, abs(ws))
        dc = 1e-6 * max(1.0, abs(wc))
        a = solve(ws + ds, wc, tau, load, sign, pin_abs, gsign, False, False, 0.0, 0.0, 0.0, 0.0, 0.0, K, S)
        b = solve(ws, wc + dc, tau, load, sign, pin_abs, gsign, False, False, 0.0, 0.0, 0.0, 0.0, 0.0, K, S)
        j00, j10 = (a[0] - fs) / ds, (a[1] - fc) / ds
        j01, j11 = (b[0] - fs) / dc, (b[1] - fc) / dc
        age = 0.0
    gh = (1.0 + 1.0 / math.sqrt(2.0)) * h
    w00, w01, w10, w11 = 1.0 - gh * j00, -gh * j01, -gh * j10, 1.0 - gh * j11
    det = w00 * w11 - w01 * w10
    k1s = (w11 * fs - w01 * fc) / det
    k1c = (w00 * fc - w10 * fs) / det
    f2 = solve(ws + h * k1s, wc + h * k1c, tau, load, sign, pin_abs, gsign, False, False, 0.0, 0.0, 0.0, 0.0, 0.0, K, S)
    r_s, r_c = f2[0] - 2.0 * k1s, f2[1] - 2.0 * k1c
    k2s = (w11 * r_s - w01 * r_c) / det
    k2c = (w00 * r_c - w10 * r_s) / det
    ws1 = ws + h * (1.5 * k1s + 0.5 * k2s)
    wc1 = wc + h * (1.5 * k1c + 0.5 * k2c)
    f1 = solve_forces(ws1, wc1, tau, load, sign, pin_abs, gsign, K, S)
    return ws1, wc1, f1, f0, (j00, j01, j10, j11, sign, age)


@_compiled
def _stored(ws, wc, K):
    return 0.5 * (K[FU.kss] * ws * ws + 2.0 * K[FU.ksc] * ws * wc + K[FU.kcc] * wc * wc)


@_compiled
def _books_open(ws, wc, ws1, wc1, f0, f1, h, tau, load, K):
    """The step's own energy balance misses by more than `balance_tol` of the energy it moved (+ `balance_floor`):
    a cheap error indicator (the same ledger as the energy guard, per step) that sends the step to error control,
    where it is halved until its halves close their books."""
    dth = 0.5 * h * (ws + ws1)
    w_in, w_out = tau * dth, load * K[FU.p] * dth
    d_e = _stored(ws1, wc1, K) - _stored(ws, wc, K)
    diss = 0.5 * h * (f0[2] + f1[2])
    return abs(w_in - w_out - d_e - diss) > (K[FU.balance_tol] * (abs(w_in) + abs(w_out) + abs(d_e) + abs(diss))
                                             + K[FU.balance_floor])



@_inlined
def _slip2(f):
    """|v_s|² of an evaluation (m²/s²)."""
    return f[8] * f[8] + f[9] * f[9] + f[10] * f[10]


@_inlined
def _transition(ws, wc, ws1, wc1, f0, f1, sign, h, tau, load, K):
    """The friction state changes within a step of length h (a speed changes sign or would by the start slope,
    the flank pair switches) or the step's own books stay open (`_books_open`)."""
    return (ws * ws1 < 0.0 or wc * wc1 < 0.0 or f1[28] != f0[28] or f0[28] != sign
            or ws * (ws + h * f0[0]) < 0.0 or wc * (wc + h * f0[1]) < 0.0
            or _books_open(ws, wc, ws1, wc1, f0, f1, h, tau, load, K))


@_compiled
def step(ws, wc, sign, pin_abs, gear, mem, tau, load, K, S):
    """One output step: error-controlled ROS2 sub-steps where the friction state changes, stick at rest.

    Returns (ω_S, ω_C, Δθ_S, Δθ_C, dissipated J, forces at the end, flank sign, pin force sum, gear force,
    solver memory). Away from friction transitions this is one ROS2 step with a frozen Jacobian (the
    common case, no extra cost). Where a speed changes sign, the flank pair switches or the slip is within
    SLIP_ZONE ε of zero (the regularised Coulomb law is stiff and far from saturation there), the step goes
    to `_controlled_step`.
    """
    h = K[FU.h]
    zone2 = (K[FU.slip_zone] * K[FU.eps_v]) ** 2
    if ws != 0.0 or wc != 0.0:  # fast path: one plain step when nothing about the friction changes
        ws1, wc1, f1, f0, m1 = rosenbrock(ws, wc, sign, pin_abs, gear, mem, tau, load, h, K, S)
        if not (_slip2(f0) < zone2 or _slip2(f1) < zone2 or _transition(ws, wc, ws1, wc1, f0, f1, sign, h, tau,
                                                                           load, K)):
            return (ws1, wc1, 0.5 * h * (ws + ws1), 0.5 * h * (wc + wc1), 0.5 * h * (f0[2] + f1[2]), f1, f1[28],
                    _pin_sum(f1), f1[12], m1)
    return _controlled_step(ws, wc, sign, pin_abs, gear, mem, tau, load, K, S)


@_compiled
def step_record(t0, th_s0, ws, th_c0, wc, w_in0, w_out0, diss0, flow0, res0, stored0, sign, pin_abs, gear, mem, tau,
                load, K, S):
    """`step` and the ledger's per-step record around it, in one call (`Fu2018`'s per-step path): from the packed
    state's first eleven items (`stepping.packed`: time, θ_S, ω_S, θ_C, ω_C, W_in, W_out, W_diss, flow,
    residual, stored energy) and its part, the record's first 21 items in `PackedOutputs` order and the end
    forces (the record's aux). The nut rides the threads: x = p θ_S, W_out = F p Δθ_S, the nut force the
    axial thread force; the books are `ledger_step`'s, the stored energy `_stored`'s. The same arithmetic in
    the same order as `stepping.packed.make_finisher`, so the record is the same bits."""
    ws1, wc1, dth_s, dth_c, diss, f1, sign, pin_abs, gear, mem = step(ws, wc, sign, pin_abs, gear, mem, tau, load,
                                                                      K, S)
    th_s = th_s0 + dth_s
    dtheta = th_s - th_s0  # as the ledger's generic form takes it: from the angles it records
    p = K[FU.p]
    w_out = load * p * dtheta
    stored1 = _stored(ws1, wc1, K)
    w_in, flow, residual, fault = ledger_step(flow0, res0, tau, dtheta, w_out, diss, stored0, stored1)
    return ((t0 + K[FU.h], th_s, ws1, th_c0 + dth_c, wc1, w_in0 + w_in, w_out0 + w_out, diss0 + diss, flow, residual,
             stored1, (sign, pin_abs, gear, mem), tau, load, diss, w_in, w_out, f1[27], p * th_s, p * ws1,
             1.0 if fault else 0.0), f1)


@_compiled
def _halves(ws, wc, sign, pin_abs, gear, tau, load, hs, f1, K, S):
    """Step doubling: the sub-step hs as two halves (a, b); `ok` when they agree with the whole step's end slip
    within `slip_tol` and each closes its books."""
    wsa, wca, fa1, fa0, ma = rosenbrock(ws, wc, sign, pin_abs, gear, NO_MEMORY, tau, load, 0.5 * hs, K, S)
    wsb, wcb, fb1, fb0, mb = rosenbrock(wsa, wca, fa1[28], _pin_sum(fa1), fa1[12], NO_MEMORY, tau, load, 0.5 * hs,
                                        K, S)
    err = math.sqrt((fb1[8] - f1[8]) ** 2 + (fb1[9] - f1[9]) ** 2 + (fb1[10] - f1[10]) ** 2)
    ok = not (err > K[FU.slip_tol] + 1e-6 * math.sqrt(fb1[8] ** 2 + fb1[9] ** 2 + fb1[10] ** 2)
              or _books_open(ws, wc, wsa, wca, fa0, fa1, 0.5 * hs, tau, load, K)
              or _books_open(wsa, wca, wsb, wcb, fb0, fb1, 0.5 * hs, tau, load, K))
    return ok, wsa, wca, fa1, fa0, ma, wsb, wcb, fb1, fb0, mb


@_inlined
def _drag_holds(tau, load, K):
    """At rest the load-independent drag alone holds the screw: the net torque τ − (L/2π) F of the frictionless
    mechanism lies within the torque the drag holds in its direction (`hold_forward`, `hold_backward`: the
    seals, the idle flanks and the pin and rolling friction their forces drive, as they run at v → 0⁺). Every
    part of it is Coulomb friction, so at rest it holds up to its sliding value: the screw breaks away at the
    no-load torque it runs with."""
    if K[FU.drag_on] == 0.0 or K[FU.hold_forward] + K[FU.hold_backward] == 0.0:
        return False
    d = tau - K[FU.p] * load
    return d <= K[FU.hold_forward] if d >= 0.0 else -d <= K[FU.hold_backward]


@_compiled
def _drag_rest(tau, load, sign, pin_abs, gear, K, S):
    """The forces at rest where the drag holds the screw (`_drag_holds`): the mechanism carries the load with
    the frictionless holding torque (L/2π) F, the drag the rest of τ."""
    return solve_forces(0.0, 0.0, K[FU.p] * load, load, sign, pin_abs, 1.0 if gear >= 0.0 else -1.0, K, S)


@_compiled
def _captured(w0s, w0c, w1s, w1c, g1, sign, pin_abs, gear, tau, load, zone2, K, S):
    """(holds, static forces): the slip passed through zero, or reached the band where the regularised law would
    creep (v_c = ε r/√(1 − r²)), while static friction can hold (`stick_forces`, r < 1)."""
    v2 = _slip2(g1)
    if w0s * w1s < 0.0 or w0c * w1c < 0.0 or v2 < zone2:
        ok, st, r = stick_forces(tau, load, sign, pin_abs, 1.0 if gear >= 0.0 else -1.0, K, S)
        if ok and r < 1.0 and (w0s * w1s < 0.0 or w0c * w1c < 0.0 or
                               v2 <= (2.0 * K[FU.eps_v] * (1.0 + r / math.sqrt(1.0 - r * r))) ** 2):
            return True, st
    # the drag's regularised laws creep within a few ε_ws of rest: where the drag can hold, it does
    if (w0s * w1s < 0.0 or abs(w1s) < 2.0 * K[FU.eps_ws]) and _drag_holds(tau, load, K):
        return True, _drag_rest(tau, load, sign, pin_abs, gear, K, S)
    return False, _NAN29


@_compiled
def _controlled_step(ws, wc, sign, pin_abs, gear, mem, tau, load, K, S):
    """`step` where the friction state changes: sub-steps checked by step doubling (`_halves`) and halved (down
    to min(dt, 1 ms)/2**MAX_HALVINGS; slow slip alone to dt/2**ZONE_HALVINGS) until the two answers agree within
    SUBSTEP_TOL ε of slip and close their books. At rest, or when the slip reaches zero (or the regularised
    creep band) while the static friction can hold (`stick_forces`, `_captured`), the mechanism sticks:
    speeds are set to zero, and the kinetic energy left (slip within a few ε: tiny) is booked as the work of
    the static friction impulse."""
    h = K[FU.h]
    zone2 = (K[FU.slip_zone] * K[FU.eps_v]) ** 2
    left = h
    hs = h
    dth_s = dth_c = diss = 0.0
    f_end = _NAN29
    while left > 1e-9 * h:
        if ws == 0.0 and wc == 0.0:
            ok, st, r = stick_forces(tau, load, sign, pin_abs, 1.0 if gear >= 0.0 else -1.0, K, S)
            if not (ok and r <= 1.0) and _drag_holds(tau, load, K):
                ok, st, r = True, _drag_rest(tau, load, sign, pin_abs, gear, K, S), 0.0
            if ok and r <= 1.0:  # inputs are held over the step: it stays stuck
                f_end, sign, gear, pin_abs = st, st[28], st[12], _pin_sum(st)
                break
        hs = min(hs, left)
        ws1, wc1, f1, f0, m1 = rosenbrock(ws, wc, sign, pin_abs, gear, mem if hs == h else NO_MEMORY, tau, load,
                                          hs, K, S)
        # sub-steps to take: the full one, or its two halves (a, b)
        two = False
        wsa, wca, fa1, fa0, ma, wsb, wcb, fb1, fb0, mb = ws1, wc1, f1, f0, m1, ws1, wc1, f1, f0, m1
        if hs > K[FU.h_min] and (_transition(ws, wc, ws1, wc1, f0, f1, sign, hs, tau, load, K)
                                 # slow slip: refined less deep (creep near the stick band's edge can last many
                                 # steps, and the layer is resolved by the checks above)
                                 or (hs > K[FU.h_zone] and (_slip2(f0) < zone2 or _slip2(f1) < zone2))):
            ok, wsa, wca, fa1, fa0, ma, wsb, wcb, fb1, fb0, mb = _halves(ws, wc, sign, pin_abs, gear, tau, load, hs,
                                                                         f1, K, S)
            if not ok:
                hs *= 0.5
                continue
            two = True
        grow = True
        for k in range(2 if two else 1):
            if not two:
                w0s, w0c, hk, w1s, w1c, g1, g0, mk = ws, wc, hs, ws1, wc1, f1, f0, m1
            elif k == 0:
                w0s, w0c, hk, w1s, w1c, g1, g0, mk = ws, wc, 0.5 * hs, wsa, wca, fa1, fa0, ma
            else:
                w0s, w0c, hk, w1s, w1c, g1, g0, mk = wsa, wca, 0.5 * hs, wsb, wcb, fb1, fb0, mb
            dth_s += 0.5 * hk * (w0s + w1s)
            dth_c += 0.5 * hk * (w0c + w1c)
            diss += 0.5 * hk * (g0[2] + g1[2])
            left -= hk
            ws, wc, sign, pin_abs, gear, mem, f_end = w1s, w1c, g1[28], _pin_sum(g1), g1[12], mk, g1
            held, st = _captured(w0s, w0c, w1s, w1c, g1, sign, pin_abs, gear, tau, load, zone2, K, S)
            if held:
                diss += _stored(ws, wc, K)
                ws = wc = 0.0
                f_end, sign, gear, pin_abs, mem = st, st[28], st[12], _pin_sum(st), NO_MEMORY
                grow = False
                break
        if grow and hs < h:
            hs *= 2.0
    return ws, wc, dth_s, dth_c, diss, f_end, sign, pin_abs, gear, mem


@_compiled
def fu2018_run(ws, wc, th_s, th_c, sign, pin_abs, gear, mem, tau_a, load_a, K, S, rows, comp):
    """The batch loop of `step` (`Fu2018._run_impl`): fills rows (n × 8: ω_S, ω_C, θ_S, θ_C, Δθ_S, dissipated,
    slip, nut force) and
    comp (n × 26, `Forces.compact`); returns the final (ω_S, ω_C, θ_S, θ_C, sign, pin force, gear force,
    memory). The ledger is the caller's (its column form, from these rows)."""
    for i in range(tau_a.shape[0]):
        ws, wc, dth, dthc, d, f1, sign, pin_abs, gear, mem = step(ws, wc, sign, pin_abs, gear, mem, tau_a[i],
                                                                  load_a[i], K, S)
        th_s += dth
        th_c += dthc
        rows[i, 0], rows[i, 1], rows[i, 2], rows[i, 3], rows[i, 4], rows[i, 5] = ws, wc, th_s, th_c, dth, d
        rows[i, 6] = math.sqrt(f1[8] ** 2 + f1[9] ** 2 + f1[10] ** 2)
        rows[i, 7] = f1[27]
        for j in range(26):
            comp[i, j] = f1[3 + j]
    return ws, wc, th_s, th_c, sign, pin_abs, gear, mem


# -- elastic --------------------------------------------------------------------------------------
@_compiled
def _power_root(d, a, b):
    """s = F^(1/3) with δ = a F^(2/3) + b F, i.e. a s² + b s³ = d (0 for d ≤ 0): the inverse of the power law
    (`elastic.power_law_root`).

    In s the law is a polynomial g(s) = a s² + b s³ − d, convex and increasing for s > 0. The iteration starts
    from an upper bound (the smaller of the pure-Hertz root √(d/a) and the pure-linear root ∛(d/b), picked by
    comparing a³ with d b² so that only one root is taken) and takes Halley's steps,
    s ← s − 2 g g' / (2 g'² − g g''), one division each, with no fractional power inside the loop. The
    stiffness and energy then follow from s without powers either (`law_evaluate`).

    Stopping: Halley's relative error after a step of relative size r is about C r³, with
    C = b s/(2a + 3bs) − ((a + 3bs)/(2a + 3bs))², so |C| ≤ 1 for this polynomial; a step below
    ROOT_STEP_TOL = 1e-6 leaves an error under 1e-18 of s, below double rounding. On `s30`'s chain
    (the shaft's compliance in series, b s/a about 0.3) that is 3.0 steps a root where Newton's took 4.5
    (the root is taken about twice per sub-step); both land within two roundings of a 50-digit root
    (tests/test_elastic.py).
    """
    return _power_root_near(d, a, b, 0.0)


@_compiled
def _power_root_near(d, a, b, near):
    """`_power_root`, started from `near` where it lies between half the upper bound and the bound: the root of
    the same law a moment before (the sub-step's last), which the force moves by a fraction of a per cent, so
    Halley's steps start within ~1e-3 and stop after two instead of three (2.1 steps a root on the bench's
    inputs, the start trusted for 94 % of the roots; tests/test_elastic.py bounds the error as `_power_root`'s)."""
    if d <= 0.0:
        return 0.0
    if a == 0.0:
        return (d / b) ** (1.0 / 3.0)
    s = math.sqrt(d / a) if b == 0.0 or a * a * a >= d * b * b else (d / b) ** (1.0 / 3.0)
    if 0.5 * s < near < s:
        s = near
    for _ in range(60):
        s2 = s * s
        r = a * s2 + b * s2 * s - d
        g1 = 2.0 * a * s + 3.0 * b * s2
        s_new = s - 2.0 * r * g1 / (2.0 * g1 * g1 - r * (2.0 * a + 6.0 * b * s))
        if abs(s_new - s) <= ROOT_STEP_TOL * s:
            return s_new
        s = s_new
    return s


@_compiled
def _stiffness_at_root(s, a, b):
    s = max(s, 1e-100)
    return s / ((2.0 / 3.0) * a + b * s)


@_compiled
def _complementary_at_root(s, a, b):
    f = s * s * s
    return 0.6 * a * (s * s * s * s * s) + 0.5 * b * f * f


@_compiled
def law_evaluate(delta, x_n, extra, E):
    """The chain law (`elastic.AxialLaw`): (F, K = dF/dδ, V, lost motion) at deflection δ and nut position x_N,
    the clearance widened by `extra`. Unpreloaded: a dead zone of the clearance, then δ = a F^(2/3) + (b + c_ext) F.
    Preloaded pair: shift x_p with δ = x_p + F c_ext, F = Q_A(δ₀ + x_p) − Q_B(δ₀ − x_p) (Newton on x_p)."""
    f, k, v, lost, _ = law_evaluate_near(delta, x_n, extra, E, 0.0)
    return f, k, v, lost


@_compiled
def law_evaluate_near(delta, x_n, extra, E, near):
    """`law_evaluate` and the unpreloaded law's root s = |F|^(1/3) (0 for a preloaded pair), its root started
    from `near` (`_power_root_near`)."""
    ell = x_n - E[EL.x_bearing]
    c_ext = max(abs(ell), 1e-6) * E[EL.inv_ea] + E[EL.c_housing]
    a, b = E[EL.law_a], E[EL.law_b]
    if E[EL.preload] > 0:
        d0 = E[EL.d0]
        x = delta / 2.0
        for _ in range(60):
            ra, rb = _power_root(d0 + x, a, b), _power_root(d0 - x, a, b)
            qa, qb = ra * ra * ra, rb * rb * rb
            ka = _stiffness_at_root(ra, a, b) if qa > 0 else 0.0
            kb = _stiffness_at_root(rb, a, b) if qb > 0 else 0.0
            f = qa - qb
            r = x + f * c_ext - delta
            dx = -r / (1.0 + (ka + kb) * c_ext)
            x += dx
            if abs(dx) <= 1e-15 * max(abs(x), d0):
                break
        ra, rb = _power_root(d0 + x, a, b), _power_root(d0 - x, a, b)
        qa, qb = ra * ra * ra, rb * rb * rb
        ka = _stiffness_at_root(ra, a, b) if qa > 0 else 0.0
        kb = _stiffness_at_root(rb, a, b) if qb > 0 else 0.0
        f = qa - qb
        k_pair = ka + kb
        k = k_pair / (1.0 + k_pair * c_ext)
        va = qa * (d0 + x) - _complementary_at_root(ra, a, b)
        vb = (qb * (d0 - x) - _complementary_at_root(rb, a, b)) if qb > 0 else 0.0
        return f, k, va + vb - 2 * E[EL.v0] + 0.5 * f * f * c_ext, 0.0, 0.0
    half = 0.5 * (E[EL.clearance] + extra)
    mag = abs(delta) - half
    if mag <= 0.0:
        return 0.0, 0.0, 0.0, delta, 0.0
    bb = b + c_ext
    r = _power_root_near(mag, a, bb, near)
    f = r * r * r
    k = _stiffness_at_root(r, a, bb)
    v = f * mag - _complementary_at_root(r, a, bb)
    sgn = 1.0 if delta > 0 else -1.0
    return sgn * f, k, v, sgn * half, r


@_compiled
def _nut_side_force(force_n, x_n, E):
    s = 1.0 if x_n - E[EL.x_bearing] >= 0 else -1.0
    return 0.5 * force_n * force_n * (s * E[EL.inv_ea])


@_compiled
def _el_force(th_s, w_s, x_n, v_n, extra, E, near):
    """The thread force with contact damping c = 2ζ√(K μ): (F + c δ̇, F, K, V, lost, δ, c, the law's root),
    the root started from `near` (`law_evaluate_near`; 0: from its bound)."""
    p = E[EL.p]
    delta = p * th_s - x_n
    f, k, v, lost, r = law_evaluate_near(delta, x_n, extra, E, near)
    c = 2.0 * E[EL.zeta] * math.sqrt(k * E[EL.mu]) if k > 0 else 0.0
    rate = p * w_s - v_n
    return f + c * rate, f, k, v, lost, delta, c, r


@_compiled
def _sliding_eff(czs, sb, mu):
    return 1.0 / (1.0 + mu / (sb * (czs - mu * sb))), 1.0 - mu / (sb * (czs + mu * sb))


@_compiled
def _excess(direction, thread_force_n, g, E):
    """|excess torque| (N m) over the running friction for motion in `direction` (sign of ω_S) at Stribeck decay
    g = exp(−(v/v_s)²): driving (ω_S F ≥ 0) p|F|/η_f(μ) less its running value; back-driven p|F| η_b(μ_c) less
    p|F| η_b(μ), with μ = μ_c + (μ_s − μ_c) g (sliding-only efficiencies, docs/model.md §4.2)."""
    mu = E[EL.mu_c] + E[EL.d_mu] * g
    eta_f, eta_b = _sliding_eff(E[EL.czs], E[EL.sin_beta], mu)
    t = abs(E[EL.p] * thread_force_n)
    return t * (1.0 / eta_f - 1.0 / E[EL.eta_rf]) if direction * thread_force_n >= 0.0 else t * (E[EL.eta_rb] - eta_b)


# (v/v_s)² above which exp(−(v/v_s)²) < 1e-12 whatever its rounding: ln(1e12) = 27.631, with a margin
STRIBECK_NEGLIGIBLE_R2 = 27.7


@_compiled
def _stribeck_torque(ws, thread_force_n, E):
    """Excess friction torque (N m, resisting ω_S) of the Stribeck law over `fu2018`'s running friction at the
    screw–roller slip v = |ω_S| p / sin β (docs/model.md §3). Zero when `breakaway_ratio` is 1 or at rest
    (`_rest_torque` then)."""
    if E[EL.breakaway] == 0.0 or ws == 0.0:
        return 0.0
    r = ws * E[EL.p_sb_vs]
    if r * r > STRIBECK_NEGLIGIBLE_R2:  # g < 1e-12 for certain: no exp, whose underflow takes libm's slow path
        return 0.0
    g = math.exp(-r * r)
    if g < 1e-12:
        return 0.0
    ex = _excess(ws, thread_force_n, g, E)
    return ex if ws > 0.0 else -ex


@_compiled
def _rest_torque(torque_nm, thread_force_n, E):
    """Screw torque the core sees at rest: the Stribeck excess at zero slip acts as extra static friction against
    the net torque τ − p F, up to its full value (the v → 0 limit of `_stribeck_torque`), so the screw breaks
    away where the running law's stick band plus that excess ends, and the friction just after breakaway is the
    friction just before it."""
    d = torque_nm - E[EL.p] * thread_force_n
    if E[EL.breakaway] == 0.0 or d == 0.0:
        return torque_nm
    ex0 = _excess(d, thread_force_n, 1.0, E)
    return torque_nm - math.copysign(min(abs(d), ex0), d)


@_compiled
def _holds(torque_nm, thread_force_n, E):
    """Static friction holds the screw at rest: the torque lies inside the breakaway band [p F η_b,s, p F/η_f,s]
    (mirrored for F < 0), efficiencies at μ_s = breakaway_ratio · μ."""
    eta_f, eta_b = E[EL.eta_sf], E[EL.eta_sb]
    t = E[EL.p] * thread_force_n
    if t >= 0:
        lo, hi = t * eta_b, t / eta_f
    else:
        lo, hi = t / eta_f, t * eta_b
    return lo <= torque_nm <= hi


@_compiled
def _core_kinetic(ws, wc, E):
    return 0.5 * (E[EL.m00] * ws * ws + 2 * E[EL.m01] * ws * wc + E[EL.m11] * wc * wc)


@_inlined
def _attempt(ws, wc, th_s, x_n, v_n, x_mid, v_el0, f_el, c, rate, f_str, sign, pin_abs, gear, mem, extra, torque_nm,
             load_n, E, K, S, near):
    """One try of a sub-step with the elastic force `f_el` (+ damping c · rate) held: the core steps (or stays
    held by static friction: `_holds`) and the nut moves under it. Returns (miss of the held force's work against
    ΔV, the Stribeck torque applied, stuck, the core's end forces, ω_S, ω_C, Δθ_S, Δθ_C, the core's dissipation,
    flank sign, pin force, gear force, solver memory, v_N, Δx_N, Δδ, the chain's F, K, V, lost motion, δ and
    damping at the end, the thread force held, the nut-side force, the law's root at the end (its next start))
    with the end's root started from `near`."""
    hs, p = K[FU.h], E[EL.p]  # the sub-step: the core's step
    f_mid = f_el + c * rate
    stuck = E[EL.breakaway] != 0.0 and ws == 0.0 and wc == 0.0 and _holds(torque_nm, f_mid, E)
    if stuck:  # static friction holds the screw: no creep below breakaway
        ff = solve_forces(0.0, 0.0, torque_nm, f_mid, sign, pin_abs, 1.0 if gear >= 0 else -1.0, K, S)
        ws1, wc1, dth_s, dth_c, d_core = 0.0, 0.0, 0.0, 0.0, 0.0
        sign1, pin1, gear1, mem1 = sign, pin_abs, gear, mem
    else:
        if ws == 0.0 and wc == 0.0:
            f_str = torque_nm - _rest_torque(torque_nm, f_mid, E)
        ws1, wc1, dth_s, dth_c, d_core, ff, sign1, pin1, gear1, mem1 = step(
            ws, wc, sign, pin_abs, gear, mem, torque_nm - f_str, f_mid, K, S)
    nsf = _nut_side_force(f_el, x_mid, E)
    v1 = v_n + hs * (f_mid - load_n + nsf) * E[EL.inv_m]
    dx = 0.5 * hs * (v_n + v1)
    d_delta = p * dth_s - dx
    _, f_el1, k1, v_el1, lost1, delta1, c1, r1 = _el_force(th_s + dth_s, ws1, x_n + dx, v1, extra, E, near)
    err = f_el * d_delta - nsf * dx - (v_el1 - v_el0)
    return (err, f_str, stuck, ff, ws1, wc1, dth_s, dth_c, d_core, sign1, pin1, gear1, mem1, v1, dx, d_delta, f_el1,
            k1, v_el1, lost1, delta1, c1, f_mid, nsf, r1)


@_inlined
def _settled(att, v_el0, torque_nm, E):
    """The attempt's held elastic force did the work ΔV (or the chain did not move): its miss creates no more
    energy than IMPACT_TOL of the input work, and takes out no more than that plus IMPACT_FLOOR of V (booked as
    the contact's loss, `_settle`). A miss that creates energy is held to IMPACT_TOL of the input work plus
    IMPACT_FLOOR of the sub-step's |ΔV|, not of V: a chain held at rest under a load near the rating stores ~40 J
    while a step moves millijoules, and misses of 1e-5 V created 1.5 % of the first steps' flow there."""
    if abs(att[15]) < 1e-15:
        return True
    tol = E[EL.impact_tol] * abs(torque_nm * att[6])
    return -(tol + E[EL.impact_floor] * abs(att[18] - v_el0)) <= att[0] <= tol + E[EL.impact_floor] * (
        abs(att[18]) + abs(v_el0))


@_inlined
def _settle(ws, wc, th_s, x_n, v_n, x_mid, v_el0, f_el, k_mid, c, rate, f_str, sign, pin_abs, gear, mem, extra,
            torque_nm, load_n, E, K, S, near):
    """A sub-step whose held elastic force does the work ΔV (`elastic_advance`): the attempt kept, its damping
    coefficient and rate, and the contact loss booked with it (J, ≥ 0).

    Attempts: the midpoint force; the discrete gradient (V₁ − V₀ + nsf Δx)/Δδ of that attempt's path; then the
    secant through the last two attempts on g(f) = gradient(f) − f. Where the path jumps with the force (the core
    stops and sticks for one force and runs on for a slightly smaller one: a flank impact reversing the screw),
    g has no root and no attempt settles: the attempt kept is then the one with the smallest miss of the held
    force's work over ΔV that is ≥ 0, and that miss is booked as the contact's loss, so the books close exactly
    and the step never creates energy (an energy-consistent contact step with non-negative numerical dissipation
    at the impact: Armero & Petőcz 1998). Where every attempt would create energy, the sub-step is unresolved
    (the last item False: `elastic_advance` redoes the output step at finer sub-steps) and the smallest miss is
    kept unbooked.

    Returns (the attempt kept, its damping coefficient and rate, the contact loss, resolved)."""
    best = _attempt(ws, wc, th_s, x_n, v_n, x_mid, v_el0, f_el, c, rate, f_str, sign, pin_abs, gear, mem, extra,
                    torque_nm, load_n, E, K, S, near)
    last, b_c, b_rate = best, c, rate
    pos, p_c, p_rate, have_pos = best, c, rate, best[0] >= 0.0  # the best attempt that creates no energy
    f_a = g_a = 0.0  # the previous attempt's held force and its g (none yet: g_a = 0)
    l_c, l_rate = c, rate
    for _attempt_no in range(int(E[EL.impact_iter])):
        if _settled(last, v_el0, torque_nm, E):
            return last, l_c, l_rate, max(last[0], 0.0), True
        # the discrete gradient for this attempt's path: nsf = −∂V/∂x_N does the work nsf Δx on the nut
        f_sec = (last[18] - v_el0 + last[23] * last[14]) / last[15]
        g_b, f_b = f_sec - f_el, f_el  # f_el: the force `last` held
        f_el = f_sec
        if g_a != 0.0 and g_b != g_a:
            # the map's slope, about −(ωh)²/4, is nearly constant over a sub-step: a secant step leaves a miss of
            # second order
            f_el = f_b - g_b * (f_b - f_a) / (g_b - g_a)
        f_a, g_a = f_b, g_b
        rate = last[15] / K[FU.h]
        # damping on the sub-step's mean rate, with the stiffer of the two tangent stiffnesses seen (at a contact
        # entry the predicted midpoint may still lie in the gap, K = 0)
        kk = max(k_mid, last[17])
        c = 2.0 * E[EL.zeta] * math.sqrt(kk * E[EL.mu]) if kk > 0 else 0.0
        last = _attempt(ws, wc, th_s, x_n, v_n, x_mid, v_el0, f_el, c, rate, last[1], sign, pin_abs, gear, mem, extra,
                        torque_nm, load_n, E, K, S, near)
        l_c, l_rate = c, rate
        if abs(last[0]) < abs(best[0]):
            best, b_c, b_rate = last, c, rate
        if last[0] >= 0.0 and (not have_pos or last[0] < pos[0]):
            pos, p_c, p_rate, have_pos = last, c, rate, True
    if _settled(last, v_el0, torque_nm, E):
        return last, l_c, l_rate, max(last[0], 0.0), True
    if not have_pos:
        return best, b_c, b_rate, 0.0, False
    return pos, p_c, p_rate, pos[0], True


@_inlined
def _refinement(x_n, E, levels):
    """j ≥ 0, the least (below `levels`) for which sub-steps of hs/2^j keep ω h ≤ `wh_refine` for the chain as
    stiff as it gets at the nut's position x_N: its flank set(s) at the static rating (`c_side`) in series with
    the shaft between the bearing and the nut and the housing. The stiffness grows as the nut nears the fixed
    bearing (the shaft shortens) far more than with the load (Hertz: K ∝ F^(1/3), bounded by the linear terms)."""
    c_ext = max(abs(x_n - E[EL.x_bearing]), 1e-6) * E[EL.inv_ea] + E[EL.c_housing]
    wh = E[EL.hs] / math.sqrt((E[EL.c_side] + c_ext) * E[EL.mu])
    j = 0
    while wh > E[EL.wh_refine] and j < levels - 1:
        wh *= 0.5
        j += 1
    return j


@_compiled
def elastic_advance(th_s, ws, th_c, wc, x_n, v_n, sign, pin_abs, gear, mem, acc, extra, torque_nm, load_n, E, KL, S):
    """One output step of `substeps` sub-steps (`elastic` module doc): (θ_S, ω_S, θ_C, ω_C, x_N, v_N, sign, pin
    force, gear force, memory, acceleration, dissipated J, load work J, end forces (29), F, K, V, lost, δ, thread
    force, stored energy at the end (`ElasticModel.total_stored_energy_j`)).

    Screw side and nut see the same thread force, taken at the sub-step's midpoint (predicted with the
    accelerations at its start): equal and opposite impulses, second order in the axial mode. Energy
    consistency of the held elastic force: its work f Δδ less the nut-side term's nsf Δx must equal the change
    of V. Where the contact closes or opens inside the sub-step (a backlash crossing, an impact) the midpoint
    force does not see it; there the sub-step is redone (`_settle`) with the discrete gradient
    (V₁ − V₀ + nsf Δx)/Δδ of the last attempt's path (Gonzalez 1996: its work is ΔV exactly), then by secant
    steps; where the path jumps with the force, the attempt kept creates no energy and its miss is booked as the
    contact's loss. The held damping force and Stribeck torque take out exactly the work they did.

    KL: the core's constants per refinement level (row j: sub-steps of hs/2^j); the step takes `substeps`·2^j
    sub-steps with j from the chain's stiffness at the nut's position (`_refinement`), and is taken again at
    j + 1 (up to the finest level KL holds) where a sub-step is unresolved (`_settle`: every attempt created
    energy). That is a stick–slip shorter than the sub-step: the screw, held at rest by its static friction,
    breaks away under the chain's force at the sub-step's start and the force its own motion builds would hold
    it again, so the path jumps between a core that turns and one that stays. The force a turning core builds
    over a sub-step grows as its square (from rest: Δθ_S = α h²/2), so finer sub-steps bring it below the
    force that holds the screw and the break-away resolves.
    """
    j = _refinement(x_n, E, len(KL))
    while True:
        out, resolved = _advance_at(j, th_s, ws, th_c, wc, x_n, v_n, sign, pin_abs, gear, mem, acc, extra, torque_nm,
                                    load_n, E, KL, S)
        if resolved or j == len(KL) - 1:
            return out
        j += 1


@_inlined
def _advance_at(j, th_s, ws, th_c, wc, x_n, v_n, sign, pin_abs, gear, mem, acc, extra, torque_nm, load_n, E, KL, S):
    """`elastic_advance` at refinement level j: (its result, every sub-step resolved or j the finest level). The
    sub-steps run to the step's end either way: a flag, not an early exit, keeps the loop as fast as it was
    (the exit cost the batch about 7 % a step), and the few steps taken again pay for the rest of theirs."""
    K = KL[j]
    last_level = j == len(KL) - 1
    resolved = True
    hs, m, p = K[FU.h], E[EL.m], E[EL.p]
    diss = w_out = 0.0
    # the law's root (its last value starts the next: `_power_root_near`)
    f_th, f_el0, k, v_el0, lost, delta, c0, root = _el_force(th_s, ws, x_n, v_n, extra, E, 0.0)
    f1 = _NAN29
    for _ in range(int(E[EL.substeps]) << j):
        a_n = (f_th - load_n + _nut_side_force(f_el0, x_n, E)) * E[EL.inv_m]
        x_mid = x_n + 0.5 * hs * v_n + 0.125 * hs * hs * a_n
        _, f_el, k_mid, _, _, _, c, root = _el_force(th_s + 0.5 * hs * ws + 0.125 * hs * hs * acc,
                                                     ws + 0.5 * hs * acc, x_mid, v_n + 0.5 * hs * a_n, extra, E, root)
        rate = p * (ws + 0.5 * hs * acc) - (v_n + 0.5 * hs * a_n)
        f_str = _stribeck_torque(ws, f_el + c * rate, E)
        best, b_c, b_rate, loss, settled = _settle(ws, wc, th_s, x_n, v_n, x_mid, v_el0, f_el, k_mid, c, rate, f_str,
                                                   sign, pin_abs, gear, mem, extra, torque_nm, load_n, E, K, S, root)
        if not (settled or last_level):
            resolved = False
        f_str = best[1]  # the Stribeck torque of the attempt kept (at rest it follows the held force)
        (_, _, stuck, f1, ws1, wc1, dth_s, dth_c, d_core, sign, pin_abs, gear, mem, v1, dx, d_delta, f_el1, k1, v_el1,
         lost1, delta1, c1, f_mid, _, root) = best
        diss += d_core + b_c * b_rate * d_delta + f_str * dth_s + loss
        acc = (ws1 - ws) / hs
        th_s += dth_s
        th_c += dth_c
        if E[EL.breakaway] != 0.0 and not stuck and abs(ws1) < E[EL.w_stick] \
                and _sticks(torque_nm, f_mid, sign, pin_abs, gear, E, K, S):
            # Karnopp: slower than the stick window with the torque inside the breakaway band (or the running
            # law's stick band widened by the static excess), the screw sticks; its kinetic energy (and the
            # carrier's) goes to friction, counted in the ledger
            diss += _core_kinetic(ws1, wc1, E)
            ws1 = wc1 = acc = 0.0
            _, f_el1, k1, v_el1, lost1, delta1, c1, root = _el_force(th_s, 0.0, x_n + dx, v1, extra, E, root)
        x_n += dx
        v_n = v1
        w_out += load_n * dx
        ws, wc = ws1, wc1
        f_el0, k, v_el0, lost, delta = f_el1, k1, v_el1, lost1, delta1
        f_th = f_el1 + c1 * (p * ws - v_n)
    # V at the end state is the last sub-step's (recomputed at the end state where the screw stuck)
    e_end = _core_kinetic(ws, wc, E) + 0.5 * m * v_n ** 2.0 + v_el0
    return (th_s, ws, th_c, wc, x_n, v_n, sign, pin_abs, gear, mem, acc, diss, w_out, f1, f_el0, k, v_el0, lost,
            delta, f_th, e_end), resolved


@_compiled
def _sticks(torque_nm, f_mid, sign, pin_abs, gear, E, K, S):
    """The torque lies inside the breakaway band (`_holds`) or the running law's stick band widened by the
    static Stribeck excess (`stick_forces` at `_rest_torque`)."""
    if _holds(torque_nm, f_mid, E):
        return True
    ok, _st, r = stick_forces(_rest_torque(torque_nm, f_mid, E), f_mid, sign, pin_abs, 1.0 if gear >= 0.0 else -1.0,
                              K, S)
    return ok and r <= 1.0


@_compiled
def elastic_run(th_s, ws, th_c, wc, x_n, v_n, sign, pin_abs, gear, mem, acc, extra, tau_a, load_a, E, KL, S, cols,
                comp):
    """The batch loop over `elastic_advance` (`ElasticModel._run_impl`). Fills cols (n × 17: θ_S, ω_S, θ_C, ω_C, x_N, v_N,
    thread force, slip, Δθ_S, the load's work, dissipated, stored energy, then the chain's F, K, V, lost, δ) and
    comp (n × 26). Returns the final (θ_S, ω_S, θ_C, ω_C, x_N, v_N, sign, pin, gear, memory, acc). The ledger
    is the caller's (its column form, from these columns)."""
    for i in range(tau_a.shape[0]):
        th0 = th_s
        (th_s, ws, th_c, wc, x_n, v_n, sign, pin_abs, gear, mem, acc, diss, w_out, f1, f_el, k, v_el, lost, delta,
         f_th, e1) = elastic_advance(th_s, ws, th_c, wc, x_n, v_n, sign, pin_abs, gear, mem, acc, extra, tau_a[i],
                                     load_a[i], E, KL, S)
        cols[i, 0], cols[i, 1], cols[i, 2], cols[i, 3], cols[i, 4], cols[i, 5] = th_s, ws, th_c, wc, x_n, v_n
        cols[i, 6], cols[i, 7] = f_th, math.sqrt(f1[8] ** 2 + f1[9] ** 2 + f1[10] ** 2)
        cols[i, 8], cols[i, 9], cols[i, 10], cols[i, 11] = th_s - th0, w_out, diss, e1
        cols[i, 12], cols[i, 13], cols[i, 14], cols[i, 15], cols[i, 16] = f_el, k, v_el, lost, delta
        for j in range(26):
            comp[i, j] = f1[3 + j]
    return th_s, ws, th_c, wc, x_n, v_n, sign, pin_abs, gear, mem, acc
