"""cos and sin inline in the kernels, without a call into the maths library.

``np.cos``/``np.sin`` compile to calls into libm. In the event loop a call costs more than the function itself:
every floating-point register is caller-saved on x86-64, so values live across it are spilled to the stack and
reloaded. The 3D orientation update (``engine.rotate``, Rodrigues) takes :func:`sincos` instead: the plates under
the hemisphere rule went from 48.6 to 43.1 ns per collision (interleaved, 3 runs each). It is not a win
everywhere: in the 2D hemisphere test on a curved wall, a branch that follows a data-dependent decision, it was
slower than libm (circle 46 -> 50 ns), so that test keeps ``np.cos``/``np.sin``.

:func:`sincos` reduces x = kπ/2 + r by Cody–Waite (π/2 split in three parts of 21 bits, each exact times any
|k| < 2³², and a rest: π/2 to about 85 bits) and evaluates fdlibm's minimax polynomials on |r| ≤ π/4 (the kernels
of its ``sin`` and ``cos``, each within an ulp there). For |x| < 6e9 it agrees with libm to a few ulp of 1
(tests/test_rules.py); beyond, and for inf and NaN, it is ``np.cos``/``np.sin`` (a branch an ordinary run never
takes: the angle is one flight's rotation τ|ω|).
"""
import numpy as np

from ._jit import jit_hot

_TWO_OVER_PI = 6.36619772367581382433e-01
# π/2 = _P1 + _P2 + _P3 + _P4: three parts of 21 bits (k·_Pi is exact for |k| < 2³²) and the rest
_P1, _P2, _P3, _P4 = 1.570796012878418, 3.139164164167596e-07, 6.223369259164557e-14, 2.912732056093356e-20
_LIMIT = 6.0e9                              # below 2³²·π/2: |k| < 2³²

# fdlibm k_sin.c and k_cos.c
_S1, _S2, _S3 = -1.66666666666666324348e-01, 8.33333333332248946124e-03, -1.98412698298579493134e-04
_S4, _S5, _S6 = 2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10
_C1, _C2, _C3 = 4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05
_C4, _C5, _C6 = -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11


@jit_hot
def sincos(x):
    """(cos x, sin x), inline (module docstring: accuracy and range)."""
    if not abs(x) < _LIMIT:
        return np.cos(x), np.sin(x)
    k = np.floor(x * _TWO_OVER_PI + 0.5)
    r = (((x - k * _P1) - k * _P2) - k * _P3) - k * _P4
    z = r * r
    s = r + r * z * (_S1 + z * (_S2 + z * (_S3 + z * (_S4 + z * (_S5 + z * _S6)))))
    c = 1.0 - 0.5 * z + z * z * (_C1 + z * (_C2 + z * (_C3 + z * (_C4 + z * (_C5 + z * _C6)))))
    q = np.int64(k) & 3
    # x = kπ/2 + r: quadrant q turns (cos r, sin r) by q quarter turns, written as selects (the quadrant of an
    # accumulated angle is random: a branch on it would be mispredicted half the time)
    odd = (q & 1) == 1
    cq = s if odd else c
    sq = c if odd else s
    return (1.0 - 2.0 * ((q + 1) >> 1 & 1)) * cq, (1.0 - 2.0 * (q >> 1 & 1)) * sq
