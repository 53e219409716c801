"""A prototype, not used by isplat: the samples of a row span 8 at a time, in SIMD lanes (issue 27 item 2).

Measured and not kept (docs/design.md, *Where a frame's time goes, per sample*): :func:`span8` (the whole
sample in lanes) and :func:`scan8` (the pixels' tests in lanes, the samples one by one) made the real chest frame
1.5x slower, though :mod:`benchmarks.simd_span` (every quad of every slice, no index) is 0.6x. To try it in the
renderer again: the patch was made against commit 63fd162 and no longer applies to later post.py and jit.py, so
``git worktree add ../simd 63fd162``, there ``cp benchmarks/_simd.py isplat/splat/simd.py``, change its three
``isplat.`` imports back to relative ones and ``git apply benchmarks/simd_post.patch`` (post.py's row loop then
calls :func:`span8` with the environment variable ``ISPLAT_SIMD_MODE=2``, :func:`scan8` with 1, the scalar loop
with ``ISPLAT_SIMD_SPAN=0``; each value with a ``NUMBA_CACHE_DIR`` of its own). These variables exist only in
the patched tree: isplat itself has no SIMD switch.

The samples of a row span 8 at a time: :func:`span8`, which :func:`isplat.splat.post._sample_square` would call
for the pixels of a row in place of its per-pixel loop where the frame allows (orthographic, no cutting planes,
no labels, no thick axis).

numba has no vector type and LLVM does not vectorise the per-pixel loop (docs/design.md, the probe of
benchmarks/sampler.py), so the vectors are explicit: a numba type of its own, :class:`Vec` (an LLVM
``<8 x double>``, ``<8 x i64>`` or ``<8 x i1>`` mask), whose operations are ``@intrinsic``\\ s emitting vector
IR. Each lane does what the scalar sample does, the same operations in the same order with no fused
multiply-add, so the images are bit for bit the scalar's (:func:`benchmarks.simd_span.check_rows` on random
rows, and the chest and head frames): the inverse map, the quad and its flags' test, the four density taps
(``llvm.masked.gather`` of the 32-bit words that end at each byte, :func:`gather_bytes`; every lane loading: a
lane that is off reads voxel 0), the bilinear density, the opacity and colour tables' lerps, the Phong factors
of the four corners weighted by their gradient magnitudes, and the compositing into the 8 pixels' RGBA (one
load of 32 values, deinterleaved, and one store; masked at the image's right edge only). Masks stand for the
branches; the pixels that saturate are marked afterwards, per set bit of their mask. On this CPU (AVX-512)
LLVM makes the gathers ``vpgather`` instructions (32 in the shaded kernel of benchmarks/simd_span.py); compiled
with ``NUMBA_CPU_NAME=x86-64-v3`` (the prebuilt kernels' level, AVX2) it was measured too.
"""

from __future__ import annotations

import os

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic, models, register_model

from isplat.jit import leaf
from isplat.splat.composite import TILE
from isplat.splat.select import CELL

N = 8
I1, I8, I32, I64 = ir.IntType(1), ir.IntType(8), ir.IntType(32), ir.IntType(64)
F32, F64 = ir.FloatType(), ir.DoubleType()


def _flat(arr):
    """An array whose elements the intrinsics address by a flat offset from its data (C-contiguous)."""
    return isinstance(arr, types.Array) and arr.layout == "C"


class Vec(types.Type):
    """An LLVM vector of 8 lanes: ``kind`` 'f' double, 'i' int64, 'b' a mask (i1)."""

    def __init__(self, kind):
        self.kind = kind
        super().__init__(name=f"Vec8{kind}")


VF, VI, VB = Vec("f"), Vec("i"), Vec("b")
_LANE = {"f": F64, "i": I64, "b": I1}


@register_model(Vec)
class _VecModel(models.PrimitiveModel):
    def __init__(self, dmm, fe_type):
        super().__init__(dmm, fe_type, ir.VectorType(_LANE[fe_type.kind], N))


def _vt(kind):
    return ir.VectorType(_LANE[kind], N)


def _splat(builder, x, kind):
    v = builder.insert_element(ir.Constant(_vt(kind), ir.Undefined), x, I32(0))
    return builder.shuffle_vector(v, ir.Constant(_vt(kind), ir.Undefined), ir.Constant(ir.VectorType(I32, N), [0] * N))


def _binop(kin, kout, emit):
    vin, vout = {"f": VF, "i": VI, "b": VB}[kin], {"f": VF, "i": VI, "b": VB}[kout]

    @intrinsic
    def op(typingctx, a, b):
        if a != vin or b != vin:
            return None
        return vout(a, b), lambda ctx, builder, sig, args: emit(builder, *args)
    return op


vadd = _binop("f", "f", lambda b, x, y: b.fadd(x, y))
vsub = _binop("f", "f", lambda b, x, y: b.fsub(x, y))
vmul = _binop("f", "f", lambda b, x, y: b.fmul(x, y))
vlt = _binop("f", "b", lambda b, x, y: b.fcmp_ordered("<", x, y))
vge = _binop("f", "b", lambda b, x, y: b.fcmp_ordered(">=", x, y))
vgt = _binop("f", "b", lambda b, x, y: b.fcmp_ordered(">", x, y))
vne = _binop("f", "b", lambda b, x, y: b.fcmp_unordered("!=", x, y))
iadd = _binop("i", "i", lambda b, x, y: b.add(x, y))
isub = _binop("i", "i", lambda b, x, y: b.sub(x, y))
imul = _binop("i", "i", lambda b, x, y: b.mul(x, y))
ilt = _binop("i", "b", lambda b, x, y: b.icmp_signed("<", x, y))
ile = _binop("i", "b", lambda b, x, y: b.icmp_signed("<=", x, y))
band = _binop("b", "b", lambda b, x, y: b.and_(x, y))
bor = _binop("b", "b", lambda b, x, y: b.or_(x, y))
iand = _binop("i", "i", lambda b, x, y: b.and_(x, y))
ishr = _binop("i", "i", lambda b, x, y: b.ashr(x, y))
ieq = _binop("i", "b", lambda b, x, y: b.icmp_signed("==", x, y))
veq = _binop("f", "b", lambda b, x, y: b.fcmp_ordered("==", x, y))


@intrinsic
def fsplat(typingctx, x):
    return VF(types.float64), lambda ctx, builder, sig, args: _splat(builder, args[0], "f")


@intrinsic
def isplat_(typingctx, x):
    return VI(types.int64), lambda ctx, builder, sig, args: _splat(builder, args[0], "i")


@intrinsic
def iota(typingctx, x):
    """x + (0, 1, ..., 7)."""
    def codegen(ctx, builder, sig, args):
        return builder.add(_splat(builder, args[0], "i"), ir.Constant(_vt("i"), list(range(N))))
    return VI(types.int64), codegen


@intrinsic
def i2f(typingctx, x):
    if x != VI:
        return None
    return VF(x), lambda ctx, builder, sig, args: builder.sitofp(args[0], _vt("f"))


@intrinsic
def f2i(typingctx, x):
    """int() of each lane (truncation)."""
    if x != VF:
        return None
    return VI(x), lambda ctx, builder, sig, args: builder.fptosi(args[0], _vt("i"))


@intrinsic
def fselect(typingctx, m, a, b):
    if m != VB or a != VF or b != VF:
        return None
    return VF(m, a, b), lambda ctx, builder, sig, args: builder.select(*args)


@intrinsic
def iselect(typingctx, m, a, b):
    if m != VB or a != VI or b != VI:
        return None
    return VI(m, a, b), lambda ctx, builder, sig, args: builder.select(*args)


@intrinsic
def bnot(typingctx, m):
    if m != VB:
        return None
    return VB(m), lambda ctx, builder, sig, args: builder.not_(args[0])


@intrinsic
def bits(typingctx, m):
    """The mask as an int, lane i bit i."""
    if m != VB:
        return None

    def codegen(ctx, builder, sig, args):
        return builder.zext(builder.bitcast(args[0], I8), I64)
    return types.int64(m), codegen


def _lane_ptrs(builder, data, idx, width):
    """The lanes' addresses ``data + idx * width`` as a vector of pointers."""
    base = _splat(builder, builder.ptrtoint(data, I64), "i")
    addr = builder.add(base, builder.mul(idx, _splat(builder, I64(width), "i")))
    return builder.inttoptr(addr, ir.VectorType(data.type, N))


def _gather(builder, data, elt, idx, width):
    """The lanes' elements at ``idx`` (every lane loads: callers give masked-off lanes a safe index)."""
    ptrs = _lane_ptrs(builder, data, idx, width)
    vt = ir.VectorType(elt, N)
    fn = cgutils.get_or_insert_function(
        builder.module, ir.FunctionType(vt, [ptrs.type, I32, ir.VectorType(I1, N), vt]),
        f"llvm.masked.gather.v{N}{_llname(elt)}.v{N}p0")
    return builder.call(fn, [ptrs, I32(width), ir.Constant(ir.VectorType(I1, N), [1] * N),
                             ir.Constant(vt, ir.Undefined)])


def _llname(elt):
    return {F64: "f64", F32: "f32"}.get(elt) or f"i{elt.width}"


def _elt_of(dtype):
    if isinstance(dtype, types.Float):
        return (F64, 8) if dtype.bitwidth == 64 else (F32, 4)
    return ir.IntType(dtype.bitwidth), dtype.bitwidth // 8


@intrinsic
def gatherf(typingctx, arr, idx):
    """``arr[idx]`` per lane (a 1-D array of unsigned ints or floats) as doubles."""
    if not (_flat(arr) and idx == VI):
        return None

    def codegen(ctx, builder, sig, args):
        data = ctx.make_array(sig.args[0])(ctx, builder, args[0]).data
        elt, width = _elt_of(sig.args[0].dtype)
        v = _gather(builder, data, elt, args[1], width)
        if isinstance(elt, ir.IntType):
            return builder.uitofp(v, _vt("f"))
        return v if elt == F64 else builder.fpext(v, _vt("f"))
    return VF(arr, idx), codegen


@intrinsic
def gather_bytes(typingctx, arr, idx):
    """``arr[idx]`` per lane of a uint8 array of at least 4 bytes, as doubles: each lane loads the 4 bytes that end
    at its byte (from the array's start for the first 3 bytes) and keeps that byte, so that a CPU with gathers
    of 32-bit words (``vpgatherqd``) gathers bytes too, reading nothing outside the array."""
    if not (_flat(arr) and arr.dtype == types.uint8 and idx == VI):
        return None

    def codegen(ctx, builder, sig, args):
        data = ctx.make_array(sig.args[0])(ctx, builder, args[0]).data
        idx = args[1]
        three = _splat(builder, I64(3), "i")
        lo = builder.sub(idx, three)
        neg = builder.icmp_signed("<", lo, _splat(builder, I64(0), "i"))
        lo = builder.select(neg, _splat(builder, I64(0), "i"), lo)
        w = _gather(builder, data, I32, lo, 1)
        shift = builder.trunc(builder.shl(builder.sub(idx, lo), three), ir.VectorType(I32, N))
        byte = builder.and_(builder.lshr(w, shift), ir.Constant(ir.VectorType(I32, N), [255] * N))
        return builder.uitofp(byte, _vt("f"))
    return VF(arr, idx), codegen


@intrinsic
def gatheri(typingctx, arr, idx):
    """``arr[idx]`` per lane (a 1-D array of unsigned ints) as int64."""
    if not (_flat(arr) and idx == VI):
        return None

    def codegen(ctx, builder, sig, args):
        data = ctx.make_array(sig.args[0])(ctx, builder, args[0]).data
        elt, width = _elt_of(sig.args[0].dtype)
        return builder.zext(_gather(builder, data, elt, args[1], width), _vt("i"))
    return VI(arr, idx), codegen


def _masked(builder, name, vt, ptr, mask, extra):
    fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(
        vt if name == "load" else ir.VoidType(),
        ([ptr.type, I32, mask.type, vt] if name == "load" else [vt, ptr.type, I32, mask.type])),
        f"llvm.masked.{name}.v{vt.count}{_llname(vt.element)}.p0")
    return builder.call(fn, extra(ptr, mask))


def _repeat(builder, mask, times):
    """Each lane of the mask ``times`` times in a row."""
    return builder.shuffle_vector(mask, ir.Constant(mask.type, ir.Undefined),
                                  ir.Constant(ir.VectorType(I32, N * times), [i // times for i in range(N * times)]))


@intrinsic
def sat_lanes(typingctx, sat, off, active):
    """Whether the 8 bytes ``sat[off:off + 8]`` are non-zero (lanes not ``active`` are not read: True)."""
    if not (_flat(sat) and active == VB):
        return None

    def codegen(ctx, builder, sig, args):
        data = ctx.make_array(sig.args[0])(ctx, builder, args[0]).data
        ptr = builder.gep(data, [args[1]])
        vt = ir.VectorType(I8, N)
        v = _masked(builder, "load", vt, ptr, args[2],
                    lambda p, m: [p, I32(1), m, ir.Constant(vt, [1] * N)])
        return builder.icmp_unsigned("!=", v, ir.Constant(vt, [0] * N))
    return VB(sat, types.int64, active), codegen


@intrinsic
def load_rgba(typingctx, img, off, mask, full):
    """The RGBA of 8 pixels from float ``img[off:off + 32]`` as 4 double vectors: all 8 when ``full`` (one plain
    load: it takes its values from the plain store of the same 8 pixels before it), else the lanes in ``mask``
    (0 in the others)."""
    if not (_flat(img) and mask == VB):
        return None

    def codegen(ctx, builder, sig, args):
        elt, width = _elt_of(sig.args[0].dtype)
        data = ctx.make_array(sig.args[0])(ctx, builder, args[0]).data
        ptr = builder.gep(data, [args[1]])
        vt = ir.VectorType(elt, 4 * N)
        m = _repeat(builder, args[2], 4)
        with builder.if_else(args[3]) as (then, other):
            with then:
                b1 = builder.block
                v1 = builder.load(builder.bitcast(ptr, vt.as_pointer()), align=width)
            with other:
                b2 = builder.block
                v2 = _masked(builder, "load", vt, ptr, m,
                             lambda p, mm: [p, I32(width), mm, ir.Constant(vt, [0.0] * 4 * N)])
        v = builder.phi(vt)
        v.add_incoming(v1, b1)
        v.add_incoming(v2, b2)
        out = []
        for ch in range(4):
            c = builder.shuffle_vector(v, ir.Constant(vt, ir.Undefined),
                                       ir.Constant(ir.VectorType(I32, N), [4 * i + ch for i in range(N)]))
            out.append(c if elt == F64 else builder.fpext(c, _vt("f")))
        return ctx.make_tuple(builder, sig.return_type, out)
    return types.UniTuple(VF, 4)(img, types.int64, mask, types.boolean), codegen


@intrinsic
def store_rgba(typingctx, img, off, r, g, b, a, mask, full):
    """Store the 8 pixels' RGBA (rounded to the image's type) at ``img[off:off + 32]``: all 8 when ``full`` (one
    plain store; the caller gives the lanes not to change their own values), else the lanes in ``mask``."""
    if not (_flat(img) and mask == VB):
        return None

    def codegen(ctx, builder, sig, args):
        elt, width = _elt_of(sig.args[0].dtype)
        data = ctx.make_array(sig.args[0])(ctx, builder, args[0]).data
        ptr = builder.gep(data, [args[1]])
        chans = [c if elt == F64 else builder.fptrunc(c, ir.VectorType(elt, N)) for c in args[2:6]]
        lo = builder.shuffle_vector(chans[0], chans[1], ir.Constant(ir.VectorType(I32, 2 * N), list(range(2 * N))))
        hi = builder.shuffle_vector(chans[2], chans[3], ir.Constant(ir.VectorType(I32, 2 * N), list(range(2 * N))))
        allc = builder.shuffle_vector(lo, hi, ir.Constant(ir.VectorType(I32, 4 * N), list(range(4 * N))))
        # allc is r0..r7 g0..g7 b0..b7 a0..a7: interleave to r0 g0 b0 a0 r1 ...
        inter = builder.shuffle_vector(allc, ir.Constant(allc.type, ir.Undefined), ir.Constant(
            ir.VectorType(I32, 4 * N), [ch * N + i for i in range(N) for ch in range(4)]))
        m = _repeat(builder, args[6], 4)
        with builder.if_else(args[7]) as (then, other):
            with then:
                builder.store(inter, builder.bitcast(ptr, inter.type.as_pointer()), align=width)
            with other:
                _masked(builder, "store", inter.type, ptr, m, lambda p, mm: [inter, p, I32(width), mm])
        return ctx.get_dummy_value()
    return types.none(img, types.int64, VF, VF, VF, VF, mask, types.boolean), codegen


@intrinsic
def vdiv1(typingctx, x):
    """1 / x per lane."""
    if x != VF:
        return None
    return VF(x), lambda ctx, builder, sig, args: builder.fdiv(_splat(builder, F64(1.0), "f"), args[0])


@leaf(inline="always")    # numba inlines its IR, not LLVM: see isplat.jit.leaf
def _phong(sflat, n00, n10, n01, n11, w00, w10, w01, w11, col):
    """``w00 * shade[n00, col] + w10 * shade[n10, col] + ...`` per lane (``n..`` the rows' flat offsets)."""
    k = isplat_(col)
    return vadd(vadd(vadd(vmul(w00, gatherf(sflat, iadd(n00, k))), vmul(w10, gatherf(sflat, iadd(n10, k)))),
                     vmul(w01, gatherf(sflat, iadd(n01, k)))), vmul(w11, gatherf(sflat, iadd(n11, k))))


@intrinsic
def _popcount(typingctx, x):
    def codegen(ctx, builder, sig, args):
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(I64, [I64]), "llvm.ctpop.i64")
        return builder.call(fn, [args[0]])
    return types.int64(types.int64), codegen


@intrinsic
def _ctz(typingctx, x):
    def codegen(ctx, builder, sig, args):
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(I64, [I64, I1]), "llvm.cttz.i64")
        return builder.call(fn, [args[0], I1(1)])
    return types.int64(types.int64), codegen




# post.SAMPLE_STAGES (read here too: post imports this module; post refuses it without a cache folder of its own)
SAMPLE_STAGES = int(os.environ.get("ISPLAT_SAMPLE_STAGES", "4"))


@leaf(forceinline=True)
def span8(y, xa, xb, every, u0, u1, v0, v1, inv, cbase, mark, nca, density, gm, nrm, strides, n_a, n_b, alpha, color,
          shade, use_gm, use_shade, img, sat, tile_sat, et):
    """Pixels ``xa..xb`` of row ``y`` of a square's scan (orthographic: ``inv``, the slice's inverse map), 8 at a
    time: what :func:`isplat.splat.post._sample_square` does per pixel (the saturation byte, the exact test of
    [u0, u1) x [v0, v1), the quad's flags in ``mark`` unless ``every``) and :func:`isplat.splat.post._sample`
    (bilinear, no thick axis) with :func:`isplat.splat.post._composite`, bit for bit. Returns (samples
    composited, pixels newly saturated)."""
    W = img.shape[1]
    ncol, ng, scol = alpha.shape[1], alpha.shape[1] // 2, shade.shape[1]
    one, zero, half = fsplat(1.0), fsplat(0.0), fsplat(0.5)
    ione, izero, ithree = isplat_(1), isplat_(0), isplat_(CELL - 1)
    k254, gmax = isplat_(254), isplat_(ng - 1)
    vu0, vu1, vv0, vv1 = fsplat(u0), fsplat(u1), fsplat(v0), fsplat(v1)
    vna, vnb = isplat_(n_a), isplat_(n_b)
    vsa, vsb = isplat_(strides[0]), isplat_(strides[1])
    vet = fsplat(2.0 if SAMPLE_STAGES < 4 else float(et))      # stages 0-3 (measuring only): no pixel saturates
    vi0, vi1, vi3, vi4 = fsplat(inv[0]), fsplat(inv[1]), fsplat(inv[3]), fsplat(inv[4])
    uy, vy = fsplat(y * inv[2]), fsplat(y * inv[5])
    vbase = isplat_(cbase)
    last = isplat_(xb)
    drawn = 0
    newly = 0
    first = isplat_(xa)
    # chunks at multiples of 8 pixels: a chunk's load then meets the store of the same 8 pixels by the square
    # before (same row, same slice) or the slice before, which the CPU forwards; overlapping chunks it does not
    for xs in range(xa - xa % N, xb + 1, N):
        lx = iota(xs)
        active = band(ile(first, lx), ile(lx, last))
        full = xs + N <= W
        live = band(active, bnot(sat_lanes(sat, y * W + xs, active)))
        if bits(live) == 0:
            continue
        xd = i2f(lx)
        u = vadd(vadd(vi0, vmul(xd, vi1)), uy)      # inv[0] + x * inv[1] + y * inv[2] (post._pixel_quad)
        v = vadd(vadd(vi3, vmul(xd, vi4)), vy)
        ok = band(live, band(band(vge(u, vu0), vlt(u, vu1)), band(vge(v, vv0), vlt(v, vv1))))
        if bits(ok) == 0:
            continue
        qa = iselect(ok, isub(f2i(vadd(u, one)), ione), izero)   # max(int(u + 1) - 1, 0): u >= -0.5 here
        qb = iselect(ok, isub(f2i(vadd(v, one)), ione), izero)
        qa = iselect(ilt(qa, izero), izero, qa)
        qb = iselect(ilt(qb, izero), izero, qb)
        if not every:       # a quad some voxel of interest touches (the flags of post._mark_cells)
            cell = iadd(imul(ishr(qb, isplat_(2)), isplat_(nca)), ishr(qa, isplat_(2)))
            flags = gatheri(mark, iselect(ok, cell, izero))
            ea, eb = ieq(iand(qa, ithree), ithree), ieq(iand(qb, ithree), ithree)
            need = bnot(ieq(iand(flags, ione), izero))
            need = bor(need, band(ea, bnot(ieq(iand(flags, isplat_(2)), izero))))
            need = bor(need, band(eb, bnot(ieq(iand(flags, isplat_(4)), izero))))
            need = bor(need, band(band(ea, eb), bnot(ieq(iand(flags, isplat_(8)), izero))))
            ok = band(ok, need)
            if bits(ok) == 0:
                continue
        if SAMPLE_STAGES == 0:
            continue
        fu = vsub(u, i2f(qa))
        fu = fselect(vgt(fu, zero), fu, zero)
        fv = vsub(v, i2f(qb))
        fv = fselect(vgt(fv, zero), fv, zero)
        i00 = iselect(ok, iadd(vbase, iadd(imul(qa, vsa), imul(qb, vsb))), izero)   # a lane that is off: voxel 0
        sa = iselect(band(ok, ilt(iadd(qa, ione), vna)), vsa, izero)               # 0 at the volume's edge
        sb = iselect(band(ok, ilt(iadd(qb, ione), vnb)), vsb, izero)
        i10 = iadd(i00, sa)
        i01 = iadd(i00, sb)
        i11 = iadd(i01, sa)
        gu, gv = vsub(one, fu), vsub(one, fv)
        w00, w10, w01, w11 = vmul(gu, gv), vmul(fu, gv), vmul(gu, fv), vmul(fu, fv)
        d = vadd(vadd(vadd(vmul(w00, gather_bytes(density, i00)), vmul(w10, gather_bytes(density, i10))),
                      vmul(w01, gather_bytes(density, i01))), vmul(w11, gather_bytes(density, i11)))
        if SAMPLE_STAGES == 1:
            drawn += _popcount(bits(band(ok, veq(d, fsplat(300.5)))))      # never: keeps the gather
            continue
        k = f2i(d)
        k = iselect(ilt(k254, k), k254, k)
        f = vsub(d, i2f(k))
        g = izero
        if use_gm:
            gs = vadd(vadd(vadd(vadd(vmul(w00, gather_bytes(gm, i00)), vmul(w10, gather_bytes(gm, i10))),
                                vmul(w01, gather_bytes(gm, i01))), vmul(w11, gather_bytes(gm, i11))), half)
            g = f2i(gs)
            g = iselect(ilt(gmax, g), gmax, g)
        ka = imul(k, isplat_(ncol))
        L = vadd(gatherf(alpha, iadd(ka, g)), vmul(f, gatherf(alpha, iadd(ka, iadd(g, isplat_(ng))))))
        ok = band(ok, vne(L, zero))
        if bits(ok) == 0:
            continue
        off = (y * W + xs) * 4
        r0, g0, b0, ai = load_rgba(img, off, ok, full)
        ta = vmul(vsub(one, ai), L)
        an = fselect(ok, vadd(ai, ta), ai)      # the lanes not composited keep their values (a full store)
        if SAMPLE_STAGES == 2:      # the opacity alone composited (for measuring only)
            store_rgba(img, off, r0, g0, b0, an, ok, full)
        else:
            cr, cg, cb = _colour(k, f, color, shade, use_shade, nrm, gm, i00, i10, i01, i11, w00, w10, w01, w11, scol)
            store_rgba(img, off, fselect(ok, vadd(r0, vmul(ta, cr)), r0), fselect(ok, vadd(g0, vmul(ta, cg)), g0),
                       fselect(ok, vadd(b0, vmul(ta, cb)), b0), an, ok, full)
        drawn += _popcount(bits(ok))
        done = bits(band(ok, band(vlt(ai, vet), vge(an, vet))))
        while done:
            x = xs + _ctz(done)
            done &= done - 1
            sat[y, x] = 1
            tile_sat[y // TILE, x // TILE] += 1
            newly += 1
    return drawn, newly


@leaf(inline="always")    # numba inlines its IR, not LLVM: see isplat.jit.leaf
def _colour(k, f, color, shade, use_shade, nrm, gm, i00, i10, i01, i11, w00, w10, w01, w11, scol):
    """The lanes' colour: the colour table's lerp, shaded with the four corners' Phong factors (weighted by their
    gradient magnitudes too when ``use_shade`` is 2), as :func:`isplat.splat.post._sample`."""
    one, zero = fsplat(1.0), fsplat(0.0)
    kc = imul(k, isplat_(6))
    cr = vadd(gatherf(color, kc), vmul(f, gatherf(color, iadd(kc, isplat_(3)))))
    cg = vadd(gatherf(color, iadd(kc, isplat_(1))), vmul(f, gatherf(color, iadd(kc, isplat_(4)))))
    cb = vadd(gatherf(color, iadd(kc, isplat_(2))), vmul(f, gatherf(color, iadd(kc, isplat_(5)))))
    if not use_shade:
        return cr, cg, cb
    n00, n10 = imul(gatheri(nrm, i00), isplat_(scol)), imul(gatheri(nrm, i10), isplat_(scol))
    n01, n11 = imul(gatheri(nrm, i01), isplat_(scol)), imul(gatheri(nrm, i11), isplat_(scol))
    if use_shade == 2:
        v00, v10 = vmul(w00, gather_bytes(gm, i00)), vmul(w10, gather_bytes(gm, i10))
        v01, v11 = vmul(w01, gather_bytes(gm, i01)), vmul(w11, gather_bytes(gm, i11))
        wsum = vadd(vadd(vadd(v00, v10), v01), v11)
        pos = vgt(wsum, zero)
        r = fselect(pos, vdiv1(wsum), one)
        w00 = fselect(pos, vmul(v00, r), w00)
        w10 = fselect(pos, vmul(v10, r), w10)
        w01 = fselect(pos, vmul(v01, r), w01)
        w11 = fselect(pos, vmul(v11, r), w11)
    s0 = _phong(shade, n00, n10, n01, n11, w00, w10, w01, w11, 0)
    s1 = _phong(shade, n00, n10, n01, n11, w00, w10, w01, w11, 1)
    if scol == 6:
        s2 = _phong(shade, n00, n10, n01, n11, w00, w10, w01, w11, 2)
        s3 = _phong(shade, n00, n10, n01, n11, w00, w10, w01, w11, 3)
        s4 = _phong(shade, n00, n10, n01, n11, w00, w10, w01, w11, 4)
        s5 = _phong(shade, n00, n10, n01, n11, w00, w10, w01, w11, 5)
        return vadd(vmul(cr, s0), s3), vadd(vmul(cg, s1), s4), vadd(vmul(cb, s2), s5)
    return vadd(vmul(cr, s0), s1), vadd(vmul(cg, s0), s1), vadd(vmul(cb, s0), s1)


@leaf(forceinline=True)
def scan8(xs, y, xa, xb, every, u0, u1, v0, v1, inv, mark, nca, sat):
    """The pixels ``xs .. xs + 7`` of row ``y`` that a square's scan samples, as the bits of an int (bit i: pixel
    ``xs + i``): in ``xa..xb``, not saturated, their point (the orthographic inverse map ``inv``) in [u0, u1) x
    [v0, v1), and in a quad that the flags in ``mark`` ask for unless ``every``: the per-pixel tests of
    :func:`isplat.splat.post._sample_square`, 8 at a time."""
    one, izero, ione, ithree = fsplat(1.0), isplat_(0), isplat_(1), isplat_(CELL - 1)
    lx = iota(xs)
    active = band(ile(isplat_(xa), lx), ile(lx, isplat_(xb)))
    live = band(active, bnot(sat_lanes(sat, y * sat.shape[1] + xs, active)))
    if bits(live) == 0:
        return 0
    xd = i2f(lx)
    u = vadd(vadd(fsplat(inv[0]), vmul(xd, fsplat(inv[1]))), fsplat(y * inv[2]))   # post._pixel_quad
    v = vadd(vadd(fsplat(inv[3]), vmul(xd, fsplat(inv[4]))), fsplat(y * inv[5]))
    ok = band(live, band(band(vge(u, fsplat(u0)), vlt(u, fsplat(u1))), band(vge(v, fsplat(v0)), vlt(v, fsplat(v1)))))
    if every or bits(ok) == 0:
        return bits(ok)
    qa = iselect(ok, isub(f2i(vadd(u, one)), ione), izero)   # max(int(u + 1) - 1, 0): u >= -0.5 here
    qb = iselect(ok, isub(f2i(vadd(v, one)), ione), izero)
    qa = iselect(ilt(qa, izero), izero, qa)
    qb = iselect(ilt(qb, izero), izero, qb)
    flags = gatheri(mark, iadd(imul(ishr(qb, isplat_(2)), isplat_(nca)), ishr(qa, isplat_(2))))
    ea, eb = ieq(iand(qa, ithree), ithree), ieq(iand(qb, ithree), ithree)
    need = bnot(ieq(iand(flags, ione), izero))
    need = bor(need, band(ea, bnot(ieq(iand(flags, isplat_(2)), izero))))
    need = bor(need, band(eb, bnot(ieq(iand(flags, isplat_(4)), izero))))
    need = bor(need, band(band(ea, eb), bnot(ieq(iand(flags, isplat_(8)), izero))))
    return bits(band(ok, need))


@leaf(inline="always")    # numba inlines its IR, not LLVM: see isplat.jit.leaf
def lowest(m):
    """The index of the lowest set bit of ``m`` (> 0)."""
    return _ctz(m)
