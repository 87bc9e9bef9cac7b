"""Prepared launches: a kernel's array arguments bound once, so a launch with the same arrays skips Taichi's
per-argument Python work.

Taichi 1.7 spends ~5-10 us of Python per array argument on every launch (the template key, type checks, building
the launch context), which for the game's 10-40-argument kernels is most of a small step's launch. `prepared(k)`
(one per kernel) is called like the kernel `k`. It keeps the last few launch contexts keyed by the identity of the
call's array arguments (ti.ndarrays and C-contiguous NumPy arrays) and its template values; the arrays are weakly
referenced, and a context is dropped as soon as one of its arrays dies (the weak reference's callback), so an
array born at a reused id never meets it and none is kept alive. Its array slots are set once, when the context
is made, each by the array's host address (a ti.ndarray's too, as a NumPy array's): Taichi's CPU launcher
(runtime/cpu/kernel_launcher.cpp) copies such a slot into the kernel's arguments on every launch and leaves it
as it was, whereas a slot set as an ndarray it marks a raw-pointer slot on the first launch while the slot still
holds the DeviceAllocation's address, so that one had to be set again before every launch (~1 us a slot, and 20
slots per chain16 FABRIK solve). On a match it sets the scalars and launches the compiled kernel. A first call, other
arrays and anything it does not handle (a return value, unsigned or vector scalars, a Fortran-ordered array, a
gradient) go through the ordinary call, which also compiles and checks; arrays are bound the second time they
are seen together, so fresh temporaries cost nothing more. On CUDA every call is the ordinary one: there
Taichi's launcher copies host arrays to the device and back around each launch, and a kept context launched
again crashed the process (segfaults in the solver tests and `play` on an H200; the cause inside Taichi was not
traced). Bound arrays must not be resized in place (NumPy's ndarray.resize). The prepared launch runs the same
compiled kernel on the same memory, so results are identical (tests/test_prepared.py).
"""

from __future__ import annotations

import operator
import weakref
from collections import OrderedDict

import numpy as np

from crowd_ik.kernels.compile_settings import compile_settings

CONTEXTS = 8  # launch contexts kept per kernel (the game alternates a few array sets: two limb poses, exports)


class Prepared:
    """`kernel` (a @ti.kernel) with its launch contexts kept; call it with the kernel's arguments."""

    def __init__(self, kernel):
        import taichi as ti
        from taichi.lang.util import cook_dtype
        from taichi.types import ndarray_type, primitive_types
        from taichi.types.utils import is_signed

        self.kernel = kernel
        self._primal = primal = kernel._primal
        self._slots = []  # per argument: (kind, launch index); kind "array", "float", "int", "template" or None
        index = 0
        for arg in primal.arguments:
            anno = arg.annotation
            if isinstance(anno, ti.template):
                self._slots.append(("template", None))
                continue
            if isinstance(anno, ndarray_type.NdarrayType):
                kind = "array"
            elif id(anno) in primitive_types.real_type_ids:
                kind = "float"
            elif id(anno) in primitive_types.integer_type_ids and is_signed(cook_dtype(anno)):
                kind = "int"
            else:
                kind = None
            self._slots.append((kind, index))
            index += 1
        on_cpu = ti.lang.impl.current_cfg().arch == ti.cpu
        self._plain = not on_cpu or primal.return_type is not None or any(kind is None for kind, _ in self._slots)
        # the key of a call: the ids of its arrays, then its template values (both picked by one C call)
        arrays = [p for p, (kind, _) in enumerate(self._slots) if kind == "array"]
        templates = [p for p, (kind, _) in enumerate(self._slots) if kind == "template"]
        self._arrays = _picker(arrays)
        self._templates = _picker(templates)
        self._floats = [(p, (i,)) for p, (kind, i) in enumerate(self._slots) if kind == "float"]
        self._ints = [(p, (i,)) for p, (kind, i) in enumerate(self._slots) if kind == "int"]
        self._contexts = OrderedDict()  # key -> (context, compiled kernel, program, weak refs)
        self._seen = OrderedDict()  # keys launched once the ordinary way

    def __call__(self, *args):
        if self._plain or len(args) != len(self._slots):
            return self.kernel(*args)
        key = (*map(id, self._arrays(args)), *self._templates(args))
        entry = self._contexts.get(key)
        if entry is None:
            self.kernel(*args)  # compiles, checks the arguments and launches
            if key in self._seen:
                self._bind(key, args)
            else:
                self._seen[key] = None
                while len(self._seen) > CONTEXTS:
                    self._seen.popitem(last=False)
            return None
        self._contexts.move_to_end(key)
        ctx, data, prog, _ = entry  # the arrays' slots stay as _bind set them
        for p, i in self._floats:
            ctx.set_arg_float(i, float(args[p]))
        for p, i in self._ints:
            ctx.set_arg_int(i, int(args[p]))
        prog.launch_kernel(data, ctx)
        return None

    def _forget(self, key) -> None:
        """An array of context `key` died (a weak reference's callback): its id may be reused, drop the context."""
        self._contexts.pop(key, None)
        self._seen.pop(key, None)

    def _bind(self, key, args) -> None:
        """A launch context for these arrays (the ordinary call has just compiled and checked them)."""
        from taichi.lang import impl
        from taichi.lang._ndarray import Ndarray
        from taichi.types import primitive_types

        primal = self._primal
        prog = impl.get_runtime().prog
        refs, arrays = [], []
        for (kind, i), a, arg in zip(self._slots, args, primal.arguments):
            if kind != "array":
                continue
            if isinstance(a, Ndarray) and a.grad is None:
                # by its host address, as a NumPy array's: a slot set so outlives launches (see the docstring)
                arrays.append(((i,), prog.get_ndarray_data_ptr_as_int(a.arr), a.arr.element_size() * a.arr.nelement(),
                               tuple(a.shape)))
            elif isinstance(a, np.ndarray) and a.flags.c_contiguous:
                dtype = arg.annotation.dtype
                element_dim = 0 if dtype is None or id(dtype) in primitive_types.type_ids else dtype.ndim
                arrays.append(((i,), int(a.ctypes.data), a.nbytes, tuple(a.shape[:a.ndim - element_dim])))
            else:
                return  # stays ordinary
            refs.append(weakref.ref(a, lambda _ref, key=key: self._forget(key)))
        instance, _ = primal.mapper.lookup(args)
        t_kernel = primal.compiled_kernels[(primal.func, instance, primal.autodiff_mode)]
        with compile_settings(**getattr(self.kernel, "compile_settings", {})):
            # under the settings of the ordinary call that compiled it (kernels/compile_settings.py)
            data = prog.compile_kernel(prog.config(), prog.get_device_caps(), t_kernel)
        ctx = t_kernel.make_launch_context()
        for i, ptr, nbytes, shape in arrays:
            ctx.set_arg_external_array_with_shape(i, ptr, nbytes, shape, 0)
        self._contexts[key] = (ctx, data, prog, refs)
        while len(self._contexts) > CONTEXTS:
            self._contexts.popitem(last=False)


def _picker(positions: list):
    """A function args -> the tuple of args at `positions` (operator.itemgetter, which gives a bare item for one)."""
    if not positions:
        return lambda args: ()
    if len(positions) == 1:
        p = positions[0]
        return lambda args: (args[p],)
    return operator.itemgetter(*positions)


_PREPARED: dict = {}


def prepared(kernel) -> Prepared:
    """The process's Prepared of `kernel` (made on first use)."""
    p = _PREPARED.get(kernel)
    if p is None:
        p = _PREPARED[kernel] = Prepared(kernel)
    return p
