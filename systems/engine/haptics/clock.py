"""The servo loop's clock inside compiled code: the monotonic clock, sleeping to a deadline and a memory fence.

The servo loop runs as one numba kernel that never takes the GIL (chainsim.systems.engine.haptics.servo),
so it reads the time and sleeps without Python: `now_ns` calls clock_gettime(CLOCK_MONOTONIC) and
`sleep_until` calls clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME), both from the C library by name
(an external symbol the kernel's cached machine code is linked against when loaded, so the kernels
cache like any other; a ctypes pointer would be an address baked into the code, which numba refuses to
cache). `fence` is a sequentially consistent fence: the seqlock through which the simulation hands the
servo a new model (servo.refresh) needs its reads and writes kept in order by the compiler and the CPU.
POSIX only (Linux, macOS 10.12+ for clock_gettime; clock_nanosleep is Linux and the BSDs).
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

CLOCK_MONOTONIC = 1
TIMER_ABSTIME = 1
_I32 = ir.IntType(32)
_P8 = ir.IntType(8).as_pointer()


def _data(context, builder, arrtype, value):
    """The data pointer of an array argument, as char*."""
    arr = cgutils.create_struct_proxy(arrtype)(context, builder, value=value)
    return builder.bitcast(arr.data, _P8)


@intrinsic
def _clock_gettime(typingctx, buf):
    """clock_gettime(CLOCK_MONOTONIC, (struct timespec *) buf.data); buf: int64[2] (seconds, nanoseconds)."""
    sig = types.int32(buf)

    def codegen(context, builder, signature, args):
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(_I32, [_I32, _P8]), "clock_gettime")
        return builder.call(
            fn, [ir.Constant(_I32, CLOCK_MONOTONIC), _data(context, builder, signature.args[0], args[0])]
        )

    return sig, codegen


@intrinsic
def _clock_nanosleep(typingctx, buf):
    """clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, buf.data, NULL): sleep until the time in buf."""
    sig = types.int32(buf)

    def codegen(context, builder, signature, args):
        fnty = ir.FunctionType(_I32, [_I32, _I32, _P8, _P8])
        fn = cgutils.get_or_insert_function(builder.module, fnty, "clock_nanosleep")
        ptr = _data(context, builder, signature.args[0], args[0])
        flags = [ir.Constant(_I32, CLOCK_MONOTONIC), ir.Constant(_I32, TIMER_ABSTIME)]
        return builder.call(fn, [*flags, ptr, ir.Constant(_P8, None)])

    return sig, codegen


@intrinsic
def fence(typingctx):
    """A sequentially consistent memory fence (compiler and CPU)."""
    sig = types.void()

    def codegen(context, builder, signature, args):
        builder.fence("seq_cst")
        return context.get_dummy_value()

    return sig, codegen


@njit(cache=True, nogil=True)
def now_ns(buf):
    """Monotonic nanoseconds (the clock time.monotonic_ns reads); buf: int64[2] scratch."""
    _clock_gettime(buf)
    return buf[0] * 1_000_000_000 + buf[1]


@njit(cache=True, nogil=True)
def sleep_until(buf, deadline_ns):
    """Sleep until the monotonic clock reads `deadline_ns` (at once if it has passed); buf: int64[2] scratch.
    A signal ends the sleep early (EINTR): the loop that called it then sleeps again."""
    buf[0] = deadline_ns // 1_000_000_000
    buf[1] = deadline_ns % 1_000_000_000
    return _clock_nanosleep(buf)


def scratch() -> np.ndarray:
    """The timespec scratch the kernels above take."""
    return np.zeros(2, dtype=np.int64)
