"""Tools for the XLA:CPU LAPACK deadlock (docs/runtime.md): an audit of compiled programs and a watchdog.

:func:`audit` answers which batched LAPACK calls of a program XLA:CPU can split
over its thread pool (the deadlock's precondition). It runs Python code in a fresh interpreter with ``--xla_dump_to``, reads every
optimised HLO module it compiled, and applies jaxlib's own rule
(``GetLapackBatchChunkSize`` in jaxlib 0.10–0.11): a call of ``B`` matrices of
``c`` flops each is split when ``B > ⌈200 000 / c⌉``. The flop formulas are
jaxlib's, per LAPACK routine. ``python tests/concurrence/deadlock_tools.py -c CODE`` prints the calls.
:func:`run_until_stalled` runs code in a child process and kills it when it stops printing.
"""

from __future__ import annotations

import argparse
import math
import os
import re
import selectors
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import NamedTuple

#: jaxlib's ``kMinWorkPerTask``: written out here, not taken from the package under test.
LAPACK_SPLIT_WORK = 200_000

_CALL = re.compile(r'custom_call_target="lapack_([sdcz])([a-z0-9]+)_ffi"')
_SHAPES = re.compile(r"operand_layout_constraints=\{(.*?)\}, [a-z_]+=")
_SIDE = re.compile(r"side = ([0-9]+)")
_SHAPE = re.compile(r"[a-z]+[0-9]*\[([0-9,]*)\]")


class LapackCall(NamedTuple):
    module: str
    routine: str
    batch: int
    cost: int  # jaxlib's flop estimate per matrix

    @property
    def splits(self) -> bool:
        return self.batch > 1 and self.batch > math.ceil(LAPACK_SPLIT_WORK / max(self.cost, 1))


def _cost(routine: str, shapes: list[tuple[int, ...]], left: bool) -> tuple[int, int]:
    """``(batch, flops per matrix)`` of one call, from its operand shapes."""
    a = shapes[0]
    m, n = (a[-2], a[-1]) if len(a) >= 2 else (1, a[-1] if a else 1)
    batch = math.prod(a[:-2]) if len(a) >= 2 else 1
    k = min(m, n)
    if routine == "trsm":  # y is the second operand
        y = shapes[1]
        m, n = y[-2], y[-1]
        return math.prod(y[:-2]), m * n * (m if left else n)
    if routine in ("geqrf", "geqp3"):
        return batch, 2 * m * n * k - (2 * k**3) // 3
    if routine in ("orgqr", "ungqr"):
        return batch, 4 * m * n * k
    if routine in ("ormqr", "unmqr"):
        c = shapes[2]
        tau = shapes[1]
        return math.prod(c[:-2]), 4 * tau[-1] * c[-2] * c[-1]
    if routine == "getrf":
        return batch, m * n * k
    if routine == "potrf":
        return batch, n**3 // 3
    if routine in ("gesdd", "gesvd", "gesvj"):
        return batch, 10 * m * n * k
    if routine in ("syevd", "heevd"):
        return batch, 5 * n**3
    if routine == "geev":
        return batch, 10 * n**3
    if routine == "gees":
        return batch, 5 * n**3
    if routine == "gehrd":
        return batch, 2 * n**3
    if routine in ("sytrd", "hetrd"):
        return batch, 4 * n**3 // 3
    if routine == "gtsv":
        b = shapes[-1]
        return math.prod(b[:-2]), b[-2] * b[-1] * 5
    return batch, 10 * m * n * k  # unknown routine: assume the dearest


def lapack_calls(hlo_text: str, module: str = "") -> list[LapackCall]:
    """Every LAPACK custom call in an optimised HLO text, with its batch and per-matrix cost."""
    calls = []
    for line in hlo_text.splitlines():
        target = _CALL.search(line)
        shapes = _SHAPES.search(line)
        if not target or not shapes:
            continue
        dims = [tuple(int(d) for d in s.split(",") if d) for s in _SHAPE.findall(shapes.group(1))]
        side = _SIDE.search(line)  # 'L' = 76, 'R' = 82
        if side is None and target.group(2) == "trsm":  # unknown side: the dearer
            batch, cost = max(_cost("trsm", dims, True), _cost("trsm", dims, False), key=lambda bc: bc[0] * bc[1])
        else:
            batch, cost = _cost(target.group(2), dims, side is None or int(side.group(1)) == 76)
        if target.group(1) in "cz":
            cost *= 3
        calls.append(LapackCall(module, target.group(2), batch, cost))
    return calls


def audit(code: str, timeout: float = 600.0) -> list[LapackCall]:
    """The LAPACK calls of every program that ``code`` compiles, run in a fresh CPU interpreter."""
    with tempfile.TemporaryDirectory() as dump:
        # no compilation cache: a program read from it is not compiled, so it would not be dumped
        env = dict(os.environ, JAX_PLATFORMS="cpu", JAXGAZE_CACHE_DIR="off",
                   XLA_FLAGS=f"{os.environ.get('XLA_FLAGS', '')} --xla_dump_to={dump} --xla_dump_hlo_as_text".strip())
        done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=timeout)
        if done.returncode != 0:
            raise RuntimeError(f"audited code failed:\n{done.stderr[-3000:]}")
        calls = []
        for path in sorted(Path(dump).glob("*after_optimizations.txt")):
            calls += lapack_calls(path.read_text(), path.name.split(".")[1])
        return calls


def run_until_stalled(code: str, args: list[str], stall_s: float, env: dict | None = None) -> tuple[bool, list[str]]:
    """Run ``python -c code args…``; ``(stalled, output lines)``: stalled if no line came for ``stall_s``.

    A stalled child is killed. A child that exits non-zero raises ``RuntimeError`` with its output's tail.
    """
    child = subprocess.Popen([sys.executable, "-c", code, *args], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                             text=True, env=env)
    selector = selectors.DefaultSelector()
    selector.register(child.stdout, selectors.EVENT_READ)
    lines, stalled = [], False
    try:
        while True:
            if not selector.select(timeout=stall_s):
                stalled = True
                break
            line = child.stdout.readline()
            if not line:
                break
            lines.append(line.rstrip())
    finally:
        if child.poll() is None:
            child.kill()
        child.wait()
    if not stalled and child.returncode != 0:
        raise RuntimeError(f"child failed ({child.returncode}):\n" + "\n".join(lines[-30:]))
    return stalled, lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-c", dest="code", required=True, help="Python code to run")
    calls = audit(parser.parse_args().code)
    for call in sorted(set(calls), key=lambda c: -c.batch * c.cost):
        print(f"{'SPLITS' if call.splits else 'ok    '} {call.routine:6s} batch {call.batch:7d} × {call.cost:7d} flops"
              f"  ({call.module})")


if __name__ == "__main__":
    main()
