"""Every fenced ``python`` and ``bash`` block of README.md and examples/README.md runs as written, from the
repository root, within a time bound: a README line that fails, or hangs, fails here naming the block.

A reader follows a document from the repository root, block after block: the blocks of one document run in
order in one folder, so a block may read what an earlier one wrote (``attend`` reads ``fit-gaze``'s video).
The folder is a fresh temporary one holding links to the repository's top-level entries, so ``examples/...``
and ``tests/data/...`` are where the READMEs say, and the outputs land in it. Each Python block has its own
imports and runs in a fresh interpreter; each shell line runs in ``bash``. ``pip install`` (CI has installed
the package) and ``pytest`` (the suite that runs this test) are the only commands not run, listed in
``NOT_RUN_COMMANDS``; what follows their ``&&`` runs. A block preceded by ``<!-- not run: REASON -->`` only
illustrates an optional extra: it is compiled (Python) or syntax-checked (bash), and the list of such blocks is
pinned in ``NOT_RUN_BLOCKS``. The processes share one JAX compilation cache (speed only: a program compiled
by one block is read back by a later one). To stay within CI's time, a shell line that both documents show
word for word, and that reads nothing an earlier line wrote, runs once: the second time its output files are
copied from the first run (which passed), as the same command on the same files would write them.
"""

import dataclasses
import os
import pathlib
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
DOCUMENTS = ("README.md", "examples/README.md")
NOT_RUN_COMMANDS = (re.compile(r"pip install( |$)"), re.compile(r"pytest$"))  # matched on the words, comments cut
NOT_RUN_BLOCKS: set[str] = set()  # ids of the blocks marked `<!-- not run: ... -->`, e.g. "README.md:180"
BLOCK_TIMEOUT_S = 300.0  # a block (all its lines) that runs longer hangs: the slowest took 101 s on 2 busy cores
TAIL = 4000


@dataclasses.dataclass(frozen=True)
class Block:
    document: str
    line: int  # of the opening fence, 1-based
    language: str
    text: str
    not_run: str | None  # the reason, for a block marked `<!-- not run: REASON -->`

    @property
    def id(self) -> str:
        return f"{self.document}:{self.line}"


def fenced_blocks(document: str) -> list[Block]:
    """The ```python and ```bash blocks of ``document`` (relative to the root), in order."""
    lines = (ROOT / document).read_text().splitlines()
    blocks, i = [], 0
    while i < len(lines):
        fence = re.fullmatch(r"```(\w+)\s*", lines[i])
        if fence is None:
            i += 1
            continue
        end = next(j for j in range(i + 1, len(lines)) if lines[j].startswith("```"))
        before = next((lines[j] for j in range(i - 1, -1, -1) if lines[j].strip()), "")
        marker = re.fullmatch(r"<!-- not run: (.+) -->", before.strip())
        if fence.group(1) in ("python", "bash"):
            blocks.append(Block(document, i + 1, fence.group(1), "\n".join(lines[i + 1:end]) + "\n",
                                marker.group(1) if marker else None))
        i = end + 1
    return blocks


BLOCKS = [block for document in DOCUMENTS for block in fenced_blocks(document)]


def shell_commands(text: str) -> list[str]:
    """The commands of a bash block to run: one per line, without those in ``NOT_RUN_COMMANDS``."""
    commands = []
    for line in text.splitlines():
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        parts = [part.strip() for part in line.split("&&")]
        kept = [part for part in parts
                if not any(rule.match(" ".join(shlex.split(part, comments=True))) for rule in NOT_RUN_COMMANDS)]
        if kept:
            commands.append(" && ".join(kept))
    return commands


@pytest.fixture(scope="module")
def environment(tmp_path_factory):
    """The environment of a reader's shell: this interpreter's ``jaxgaze`` and ``python`` first on PATH,
    one compilation cache for this module's processes, figures without a display."""
    env = dict(os.environ)
    env["PATH"] = os.pathsep.join([str(pathlib.Path(sys.executable).parent), env.get("PATH", "")])
    cache = str(tmp_path_factory.mktemp("jax_cache"))
    env.update(JAXGAZE_CACHE_DIR=cache, JAX_COMPILATION_CACHE_DIR=cache, JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0",
               JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES="0", MPLBACKEND="Agg", PYTHONUNBUFFERED="1")
    return env


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    """One working folder per document, each holding a link to every top-level entry of the repository."""
    made = {}
    for document in DOCUMENTS:
        folder = made[document] = tmp_path_factory.mktemp(pathlib.Path(document).stem)
        for entry in ROOT.iterdir():
            if entry.name != ".git":
                (folder / entry.name).symlink_to(entry, target_is_directory=entry.is_dir())
    return made


def _run(argv: list[str], folder: pathlib.Path, env: dict, timeout_s: float) -> tuple[int | None, str]:
    """Run ``argv`` in ``folder``; (exit status or None on a timeout, the output's tail). A timed-out
    command is killed with its whole process group."""
    process = subprocess.Popen(argv, cwd=folder, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                               stdin=subprocess.DEVNULL, text=True, start_new_session=True)
    try:
        output, _ = process.communicate(timeout=max(timeout_s, 1.0))
        return process.returncode, output[-TAIL:]
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        output, _ = process.communicate()
        return None, output[-TAIL:]


RAN: dict[tuple, dict] = {}  # a shell line's words → copies of the files it wrote, {name: path}


def _outputs(folder: pathlib.Path) -> dict:
    """``{name: mtime}`` of the files in ``folder`` that are not links into the repository."""
    return {p.name: p.stat().st_mtime_ns for p in folder.iterdir() if not p.is_symlink() and p.is_file()}


def _failure(block: Block, what: str, status: int | None, output: str, timeout_s: float) -> str:
    verdict = f"did not finish within {timeout_s:.0f} s" if status is None else f"exited {status}"
    return (f"{block.id} ({block.language} block): {what!r} {verdict}\n--- the block ---\n{block.text}"
            f"--- the output's tail ---\n{output}")


def test_blocks_found_and_not_run_ones_pinned():
    """The parser sees the READMEs' blocks, and a block marked not-run is one the list above names."""
    assert sum(block.document == "README.md" for block in BLOCKS) >= 10
    assert sum(block.document == "examples/README.md" for block in BLOCKS) >= 6
    assert {block.id for block in BLOCKS if block.not_run} == NOT_RUN_BLOCKS


@pytest.mark.parametrize("block", BLOCKS, ids=[f"{block.id}-{block.language}" for block in BLOCKS])
def test_readme_block_runs(block, environment, folders):
    folder = folders[block.document]
    if block.not_run:  # an illustration of an optional extra: it must at least parse
        if block.language == "python":
            compile(block.text, block.id, "exec")
        else:
            status, output = _run(["bash", "-n", "-c", block.text], folder, environment, 30.0)
            assert status == 0, output
        return
    start = time.monotonic()
    if block.language == "python":
        script = folder / f"readme_block_{block.line}.py"
        script.write_text(block.text)
        status, output = _run([sys.executable, script.name], folder, environment, BLOCK_TIMEOUT_S)
        assert status == 0, _failure(block, "the block", status, output, BLOCK_TIMEOUT_S)
        return
    commands = shell_commands(block.text)
    assert commands, f"{block.id}: a bash block with nothing to run"
    for command in commands:
        words = tuple(shlex.split(command, comments=True))
        before = _outputs(folder)
        reads_outputs = any(word in before for word in words)  # a file an earlier line wrote
        if words in RAN and not reads_outputs:  # shown and run before, on the same files
            for name, path in RAN[words].items():
                shutil.copy2(path, folder / name)
            continue
        left = BLOCK_TIMEOUT_S - (time.monotonic() - start)
        status, output = _run(["bash", "-o", "pipefail", "-c", command], folder, environment, left)
        assert status == 0, _failure(block, command, status, output, BLOCK_TIMEOUT_S)
        if reads_outputs:
            continue
        stash = folder.parent / f"readme_outputs_{len(RAN)}"  # as written now: later lines may overwrite them
        stash.mkdir()
        RAN[words] = {name: shutil.copy2(folder / name, stash / name) for name, mtime in _outputs(folder).items()
                      if before.get(name) != mtime}
