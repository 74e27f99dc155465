"""Launching a Taichi kernel again with less Python on the way (the device path).

Taichi 1.7's ``kernel(*args)`` does, at every call, in Python: the arguments'
features looked up to find the compiled instance, each argument checked and
set through a dispatch over every kind Taichi knows, and the program's
compile-or-load step (a cache lookup that hashes the kernel). On an H200 this
cost 0.2-0.4 ms per launch of the step kernel (12 arguments), more than the
step itself in f32 (0.18 ms at 4096 x 4096): the GPU waited for Python.

:func:`fast` wraps a kernel: the first call with a given kind of each argument
goes through Taichi as always (it compiles, checks and launches); the wrapper
then keeps the compiled instance and Taichi's compiled data, and later calls
with the same kinds set the arguments straight into a launch context
(ndarrays, device tensors by address, scalars by the kernel's declared type)
and launch it: a few microseconds of Python. The kernel, its arguments and
its results are the same; only the route to the launch is shorter. Anything
else (host arrays, template arguments, another Taichi runtime since) takes
the ordinary call.
"""

__all__ = ["fast"]


def fast(kernel):
    """The fast-launching wrapper of ``kernel`` (one per kernel, kept on it)."""
    wrapper = getattr(kernel, "_ipc_fast", None)
    if wrapper is None:
        wrapper = _FastKernel(kernel)
        kernel._ipc_fast = wrapper
    return wrapper


class _FastKernel:
    def __init__(self, kernel):
        from taichi.lang import impl
        from taichi.lang._ndarray import Ndarray
        from taichi.lang.util import cook_dtype
        from taichi.types import ndarray_type, primitive_types
        from taichi.types.utils import is_signed

        self.kernel = kernel
        self.primal = getattr(kernel, "_primal", None)
        self._impl = impl
        self._ndarray = Ndarray
        self.cache = {}
        # how each argument is set, from the kernel's declared types
        self.setters = None
        if self.primal is None:
            return
        setters = []
        for argument in self.primal.arguments:
            needed = argument.annotation
            if id(needed) in primitive_types.real_type_ids:
                setters.append("float")
            elif id(needed) in primitive_types.integer_type_ids:
                setters.append("int" if is_signed(cook_dtype(needed)) else "uint")
            elif isinstance(needed, ndarray_type.NdarrayType):
                setters.append("array")
            else:  # templates, matrices, structs: the ordinary call
                return
        self.setters = tuple(setters)

    def _kinds(self, args):
        """The arguments' kinds, or None where one needs the ordinary call."""
        kinds = []
        for setter, value in zip(self.setters, args):
            if setter != "array":
                kinds.append(setter)
            elif isinstance(value, self._ndarray):
                if value.grad is not None:
                    return None
                kinds.append(("nd", id(value.dtype), len(value.shape)))
            elif type(value).__module__.split(".", 1)[0] == "torch" and value.is_cuda \
                    and value.is_contiguous() and not value.requires_grad:
                kinds.append(("tensor", str(value.dtype), value.dim()))
            else:
                return None
        return tuple(kinds)

    def __call__(self, *args):
        if self.setters is None or len(args) != len(self.setters):
            return self.kernel(*args)
        kinds = self._kinds(args)
        if kinds is None:
            return self.kernel(*args)
        prog = self._impl.get_runtime().prog
        hit = self.cache.get(kinds)
        if hit is None or hit[0] is not prog:
            result = self.kernel(*args)  # compiles, checks, launches
            key = self.primal.ensure_compiled(*args)
            t_kernel = self.primal.compiled_kernels[key]
            data = prog.compile_kernel(prog.config(), prog.get_device_caps(), t_kernel)
            self.cache[kinds] = (prog, t_kernel, data)
            return result
        _, t_kernel, data = hit
        ctx = t_kernel.make_launch_context()
        for i, (kind, value) in enumerate(zip(kinds, args)):
            index = (i,)
            if kind == "float":
                ctx.set_arg_float(index, float(value))
            elif kind == "int":
                ctx.set_arg_int(index, int(value))
            elif kind == "uint":
                ctx.set_arg_uint(index, int(value))
            elif kind[0] == "nd":
                ctx.set_arg_ndarray(index, value.arr)
            else:
                ctx.set_arg_external_array_with_shape(
                    index, int(value.data_ptr()), value.element_size() * value.nelement(),
                    tuple(value.shape), 0)
        prog.launch_kernel(data, ctx)
        return None
