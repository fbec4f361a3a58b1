"""Give the path tracer's JIT code names under Linux ``perf``: render a scene for a while,
then write ``/tmp/perf-PID.map`` (perf's map of JIT symbols) naming every function numba
compiled for the scene's kernel, so that ``perf report`` shows ``_trace_samples``,
``sample_pc2d_kernel``, ``envmap_uv``... instead of bare addresses:

    NUMBA_NUM_THREADS=1 perf record -o perf.data python benchmarks/perf_tracer.py SCENE
    perf report -i perf.data --no-children --sort sym

``--dump DIR`` also writes each function's machine code to ``DIR/<address>.bin``
(``objdump -D -b binary -m i386:x86-64 --adjust-vma=0x<address>`` disassembles it), for
instruction-level counts from ``perf script -F ip,sym``. Functions inlined into the
kernel (the BVH traversal, the emitters) count as the kernel's own time.

The kernel is compiled in this process (numba keeps the LLVM module only for what it
compiled itself, not for what it loads from its cache), in fresh temporary caches:
expect a minute of compilation before the timed renders.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import tempfile
import time

import _args  # benchmarks/_args.py, beside this script


def short_name(mangled: str) -> str:
    """The function's own name from numba's mangled symbol (``cfunc.``/``cpython.``
    wrappers marked as such)."""
    i = mangled.find("_ZN")
    if i < 0:
        return mangled
    rest, parts = mangled[i + 3:], []
    while rest[:1].isdigit():
        digits = re.match(r"\d+", rest).group()
        size = int(digits)
        parts.append(rest[len(digits):len(digits) + size])
        rest = rest[len(digits) + size:]
    prefix = "cfunc:" if mangled.startswith("cfunc") else ""
    if parts and parts[0] == "cpython":
        prefix, parts = "cpython:", parts[1:]
    return prefix + (parts[-1] if parts else mangled)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene")
    ap.add_argument("--seconds", type=_args.seconds, default=20.0, help="time spent rendering")
    ap.add_argument("--res", type=_args.count, default=128)
    ap.add_argument("--spp", type=_args.count, default=64)
    ap.add_argument("--dump", metavar="DIR", help="write each function's machine code here")
    ap.add_argument("--image-only", action="store_true",
                    help="render the image alone (variance=False), as `mcverify bench` times")
    a = ap.parse_args()
    scratch = tempfile.mkdtemp(prefix="perf-tracer-")
    os.environ["MCVERIFY_CACHE"] = os.path.join(scratch, "kernels")
    os.environ["NUMBA_CACHE_DIR"] = os.path.join(scratch, "numba")

    import ctypes

    from estimators.pathtracer import prepare_scene, render
    from mcverify.gate.reference import resolve_scene

    module = sys.modules["estimators.pathtracer.render"]
    scene = prepare_scene(resolve_scene(a.scene)[1], params={"res": a.res})
    variance = not a.image_only
    render(scene, spp=a.spp, variance=variance)               # compiles the kernel
    t0, renders = time.perf_counter(), 0
    while time.perf_counter() - t0 < a.seconds:
        render(scene, spp=a.spp, variance=variance)
        renders += 1
    kernel = module.specialised_kernel(scene.features)
    symbols = {}
    for attr in dir(kernel):
        for cres in getattr(getattr(kernel, attr), "overloads", {}).values():
            lib = cres.library
            for f in lib._final_module.functions:
                if not f.is_declaration:
                    address = lib.get_pointer_to_function(f.name)
                    if address:
                        symbols[address] = short_name(f.name)
    mapped = []
    with open("/proc/self/maps") as f:
        for line in f:
            lo, hi = (int(x, 16) for x in line.split()[0].split("-"))
            mapped.append((lo, hi))
    addresses = sorted(symbols)
    path = f"/tmp/perf-{os.getpid()}.map"
    with open(path, "w") as out:
        for i, address in enumerate(addresses):
            end = next((hi for lo, hi in mapped if lo <= address < hi), address)
            nxt = addresses[i + 1] if i + 1 < len(addresses) else end
            size = max(min(nxt, end) - address, 1)
            out.write(f"{address:x} {size:x} {symbols[address]}\n")
            if a.dump:
                os.makedirs(a.dump, exist_ok=True)
                with open(os.path.join(a.dump, f"{address:x}.bin"), "wb") as code:
                    code.write(ctypes.string_at(address, size))
    print(f"{renders} renders of {a.scene} in {a.seconds:g} s; {len(addresses)} JIT "
          f"functions named in {path}")


if __name__ == "__main__":
    _args.run(main)
