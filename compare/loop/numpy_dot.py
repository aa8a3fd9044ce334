r"""numpy's dot of two 3-vectors in compiled code (numba), bit for bit.

numpy's ``dot`` (and ``@``, and ``np.linalg.norm`` as :math:`\sqrt{x \cdot x}`) of two float
3-vectors is OpenBLAS's ``ddot``, whose short-vector loop is :math:`s \leftarrow s + x_i y_i`
from :math:`s = 0`, each multiply-add fused where the CPU has FMA. :func:`dot3` repeats that
chain, fused or not; :func:`numpy_dot_order` finds which one numpy uses on this machine, so a
kernel can give the numbers of the numpy code it replaces (``tests/compare/loop/test_sigma_kernel.py``).
"""

from __future__ import annotations

import numba
import numpy as np
from numba import types
from numba.extending import intrinsic


@intrinsic
def _fma(typingctx, a, b, c):  # noqa: ANN001, ANN202 (numba's typing signature)
    """a·b + c rounded once (LLVM's ``llvm.fma.f64``: the CPU's FMA, or libm's exact one)."""
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, signature, args):  # noqa: ANN001, ANN202
        return builder.fma(*args)

    return sig, codegen


@numba.njit(cache=True, nogil=True)
def dot3(x0: float, x1: float, x2: float, y0: float, y1: float, y2: float, fused: bool) -> float:
    """``numpy.dot`` of (x0, x1, x2) and (y0, y1, y2): 0 + x0·y0 + x1·y1 + x2·y2 in that order, fused or not."""
    if fused:
        s = _fma(x2, y2, _fma(x1, y1, _fma(x0, y0, 0.0)))
    else:
        s = ((0.0 + x0 * y0) + x1 * y1) + x2 * y2
    return 0.0 + s


def numpy_dot_order() -> bool | None:
    """Whether numpy's dot of 3-vectors is :func:`dot3`'s fused chain (True), its plain one (False), or neither (None).

    Probed on pairs whose fused and plain results differ, so a fused dot cannot pass as plain.
    """
    rng = np.random.default_rng(20261206)
    fused_ok = plain_ok = True
    differ = 0
    for _ in range(64):
        x, y = rng.normal(size=3), rng.normal(size=3) * 1e3
        want = float(x.dot(y))
        fused, plain = dot3(*x.tolist(), *y.tolist(), True), dot3(*x.tolist(), *y.tolist(), False)
        differ += fused != plain
        fused_ok &= want == fused
        plain_ok &= want == plain
    if differ == 0:  # nothing told the two apart: cannot know
        return None
    return True if fused_ok else False if plain_ok else None


NUMPY_DOT_FUSED: bool | None = numpy_dot_order()
"""numpy's 3-vector dot on this machine: the fused chain, the plain one, or None (neither: use numpy)."""
