"""The manual's examples run: README.md and every page of docs/.

Each page is one test. Its examples run in page order in a temporary directory that holds a copy of
``examples/`` (the working directory while they run), so an example may use a file an earlier one of the
page wrote (``ms.parquet``, ``bench_run.mf4``), and nothing is written into the repository: the test
checks that ``examples/`` is unchanged afterwards.

- A fenced ``python`` block runs as a script; the page's blocks share one namespace, as in a notebook (a
  page may split a long example in parts). A block with ``>>>`` prompts is a doctest of its own, and what
  it prints must match (whitespace normalised, ``...`` allowed).
- A line ``$ drivecal ARGS`` in a ``text``, ``console`` or plain fenced block runs the command in this
  process (``drivecal.cli.main``; ``\\`` continues a line, ``# comment`` and ``> /dev/null`` are dropped).
  The lines after it, up to the next ``$``, are the output pasted from a real run: every one must be in
  what the command printed (stdout and stderr; whitespace collapsed, so a line wrapped at another terminal
  width still matches; a ``...`` line stands for lines left out). The exit status must be the one
  ``; echo $?`` or a following ``$ echo $?`` shows; else 2 when the paste ends in a ``drivecal: error:``
  line; else the one a pasted ``verdict:`` (and ``specification:``) line stands for (``drivecal fit``
  exits with it); else 0.
- A line ``$ sed ...`` (or ``cp``, ``cat``, another of ``SHELL_HELPERS``) prepares a file for the next
  command: it runs with ``/bin/sh`` in the same folder, redirections and all, and is checked the same way.

Markers, HTML comments right above a block (invisible on the rendered page):

- ``<!-- docs-test: file NAME -->``: the block is a file the page shows (a motor file, a bench-file
  excerpt); its text is written to ``NAME`` in the page's folder, for the examples after it.
- ``<!-- docs-test: slow REASON -->``: an example that takes more than ~20 s (a saturating or
  effect-selecting fit, the demo, a batch). It runs; its page becomes a ``slow`` test.
- ``<!-- docs-test: skip REASON -->``: an example that is not run, with the reason. Commands under a ``sh`` fence are recipes and
synopses, not runs: they are not executed.
"""

from __future__ import annotations

import contextlib
import doctest
import hashlib
import io
import os
import re
import shlex
import shutil
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
MARKER = re.compile(r"<!--\s*docs-test:\s*(skip|slow|file)\b\s*(.*?)\s*-->")
FENCE = re.compile(r"^(\s*)(`{3,})\s*([\w+-]*)")
SHELL_FENCES = {"", "text", "console"}
#: Print each example's wall and CPU time (to choose what to skip): DRIVECAL_DOCS_TIMES=1 pytest -s ...
TIMES = os.environ.get("DRIVECAL_DOCS_TIMES") == "1"


@dataclass
class Block:
    page: Path
    line: int  # 1-based line of the opening fence
    lang: str
    text: str
    skip: str | None  # the reason given in the page, or None
    slow: str | None = None  # run, in the page's slow test only: the reason (its time) given in the page
    file: str | None = None  # not run: its text is written to this file of the page's folder


@dataclass
class Command:
    line: int
    argv: list[str]
    expected: list[str] = field(default_factory=list)
    status: int | None = None  # from `; echo $?` or a following `$ echo $?`
    shell: str | None = None  # a helper line (`sed`, `cp`, ...) run by the shell, not drivecal


#: The shell's own commands a page may use to prepare a file for drivecal (run with /bin/sh in the page's folder).
SHELL_HELPERS = {"sed", "cp", "mv", "cat", "head", "tail", "mkdir", "rm", "printf", "echo"}


def blocks(page: Path) -> list[Block]:
    """The fenced blocks of a page, with the skip marker that stands right above each (blank lines allowed)."""
    lines = page.read_text(encoding="utf-8").split("\n")
    out, i = [], 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        indent, ticks, lang = m.groups()
        j = i + 1
        while j < len(lines) and not lines[j].strip().startswith(ticks):
            j += 1
        body = [line[len(indent):] if line.startswith(indent) else line for line in lines[i + 1:j]]
        k = i - 1
        while k >= 0 and not lines[k].strip():
            k -= 1
        marker = MARKER.search(lines[k]) if k >= 0 else None
        kind, value = marker.groups() if marker else (None, None)
        out.append(Block(page, i + 1, lang, "\n".join(body),
                         skip=(value or "no reason given") if kind == "skip" else None,
                         slow=(value or "no reason given") if kind == "slow" else None,
                         file=value if kind == "file" else None))
        i = j + 1
    return out


def commands(block: Block) -> list[Command]:
    """The ``$ drivecal ...`` commands of a shell-output block with their pasted output."""
    out: list[Command] = []
    lines = block.text.split("\n")
    i = 0
    while i < len(lines):
        line = lines[i]
        if not line.startswith("$ "):
            if out:
                out[-1].expected.append(line)
            i += 1
            continue
        start = i
        cmd = line[2:]
        while cmd.rstrip().endswith("\\") and i + 1 < len(lines):
            i += 1
            cmd = cmd.rstrip()[:-1] + " " + lines[i].strip()
        i += 1
        if cmd.strip() == "echo $?":
            assert out, f"{block.page.name}:{block.line + start + 1}: `echo $?` with no command before it"
            out[-1].status = int(lines[i].strip())
            i += 1
            continue
        echo = "; echo $?" in cmd
        cmd = cmd.replace("; echo $?", "")
        argv = shlex.split(cmd.replace("> /dev/null", ""), comments=True)
        if argv and argv[0] in SHELL_HELPERS:
            command = Command(block.line + start + 1, argv, shell=cmd)
        elif not argv or argv[0] != "drivecal":
            raise AssertionError(f"{block.page.name}:{block.line + start + 1}: only drivecal commands and "
                                 f"{sorted(SHELL_HELPERS)} run: {line}")
        else:
            command = Command(block.line + start + 1, argv[1:])
        if echo:
            command.status = int(lines[i].strip())
            i += 1
        out.append(command)
    return out


#: `drivecal fit`'s exit status for the verdict and the specification it prints (docs/exit-statuses.md).
VERDICTS = {"calibrated": 0, "partially calibrated": 3, "model mismatch suspected": 4, "not calibrated": 5}
SPECIFICATIONS = {"pass": 0, "fail": 6, "inconclusive": 7, "not calibrated": None}


def expected_status(command: Command) -> int:
    expected = [line for line in command.expected if line.strip()]
    if command.status is not None:
        return command.status
    if expected and expected[-1].startswith("drivecal: error:"):
        return 2
    status = 0
    for line in expected:
        for prefix, table in (("verdict: ", VERDICTS), ("specification: ", SPECIFICATIONS)):
            if line.startswith(prefix):
                word = next((w for w in sorted(table, key=len, reverse=True) if line[len(prefix):].startswith(w)), None)
                assert word is not None, f"line {command.line}: unknown {prefix.strip()} {line!r}"
                status = table[word] if table[word] is not None else status
    return status


def _normal(text: str) -> str:
    return " ".join(text.split())


def run_command(command: Command, where: str) -> None:
    from drivecal.cli import main

    if command.shell is not None:
        done = subprocess.run(["/bin/sh", "-c", command.shell], capture_output=True, text=True)
        status, printed = done.returncode, done.stdout + "\n" + done.stderr
    else:
        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                status = main(command.argv)
            except SystemExit as exc:
                status = exc.code if isinstance(exc.code, int) else 1
        printed = out.getvalue() + "\n" + err.getvalue()
    expected = [line for line in command.expected if line.strip()]
    want = expected_status(command)
    assert status == want, f"{where}: exit status {status}, the page says {want}\n{printed}"
    have = _normal(printed)  # one line: the terminal's wrapping (its width) does not matter
    missing = [line for line in expected if line.strip() != "..." and _normal(line) not in have]
    assert not missing, (f"{where}: {len(missing)} line(s) of the pasted output are not in what "
                         f"`{command.shell or 'drivecal ' + shlex.join(command.argv)}` printed, first: {missing[0]!r}\n"
                         f"--- printed:\n{printed}")


def run_python(block: Block, where: str, namespace: dict) -> None:
    if ">>> " in block.text:
        parser = doctest.DocTestParser()
        test = parser.get_doctest(block.text, {}, where, str(block.page), block.line)
        runner = doctest.DocTestRunner(optionflags=doctest.NORMALIZE_WHITESPACE | doctest.ELLIPSIS)
        report = io.StringIO()
        runner.run(test, out=report.write)
        assert runner.failures == 0, f"{where}: the doctest's output differs\n{report.getvalue()}"
    else:
        exec(compile(block.text, where, "exec"), namespace)


def _tree_digest(folder: Path) -> str:
    h = hashlib.sha256()
    for path in sorted(folder.rglob("*")):
        h.update(str(path.relative_to(folder)).encode())
        if path.is_file():
            h.update(path.read_bytes())
    return h.hexdigest()


def test_pages_are_found():
    names = {page.name for page in PAGES}
    assert {"README.md", "index.md", "getting-started.md", "fitting.md", "cli.md"} <= names


def test_the_readme_and_the_guide_have_examples_that_run():
    for name in ("README.md", "getting-started.md", "plans.md", "fitting.md", "python-api.md"):
        page = next(p for p in PAGES if p.name == name)
        assert any(_runnable(b) and b.skip is None for b in blocks(page)), name


def test_skip_markers_give_a_reason():
    for page in PAGES:
        for block in blocks(page):
            assert block.skip != "no reason given", f"{page.name}:{block.line}: say why the example is skipped"
            assert block.slow != "no reason given", f"{page.name}:{block.line}: say how long the example takes"
            assert block.file != "", f"{page.name}:{block.line}: name the file the block is written to"


def _runnable(block: Block) -> bool:
    return block.lang == "python" or (block.lang in SHELL_FENCES and "\n$ " in "\n" + block.text)


#: The pages with examples (run or marked skipped); the others have nothing to run.
EXAMPLE_PAGES = [page for page in PAGES if any(_runnable(block) for block in blocks(page))]
#: Pages whose examples take over ~5 min on 2 cores: ``long`` tests (``make test-long`` runs them, ``make test`` not).
#: bench-effects.md selects the three bench effects of an inverter bench and the iron bridge of a PM-SyRM (417 s).
LONG_PAGES = ("bench-effects.md",)
#: A page with a slow example runs as a slow test (``-m "not slow"`` leaves it out): its examples share files.
PAGE_PARAMS = [pytest.param(page, id=page.name,
                            marks=([pytest.mark.slow] if any(b.slow for b in blocks(page)) else [])
                            + ([pytest.mark.long] if page.name in LONG_PAGES else []))
               for page in EXAMPLE_PAGES]


@pytest.mark.parametrize("page", PAGE_PARAMS)
def test_examples_of_the_page_run(page, tmp_path, monkeypatch):
    examples = ROOT / "examples"
    before = _tree_digest(examples)
    shutil.copytree(examples, tmp_path / "examples")
    monkeypatch.chdir(tmp_path)
    ran, namespace = 0, {"__name__": "__docs__"}
    for block in blocks(page):
        where = f"{page.relative_to(ROOT)}:{block.line}"
        if block.file:
            target = tmp_path / block.file
            assert target.resolve().is_relative_to(tmp_path.resolve()) and not target.exists(), f"{where}: {block.file}"
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text(block.text + "\n", encoding="utf-8")
            continue
        if not _runnable(block) or block.skip is not None:
            continue
        t0, c0 = time.perf_counter(), time.process_time()
        if block.lang == "python":
            run_python(block, where, namespace)
        else:
            for command in commands(block):
                run_command(command, f"{page.relative_to(ROOT)}:{command.line}")
        ran += 1
        if TIMES:
            print(f"\n{where}: {time.perf_counter() - t0:.1f} s wall, {time.process_time() - c0:.1f} s CPU")
    assert _tree_digest(examples) == before, "an example wrote into examples/"
    if ran == 0:
        pytest.skip(f"{page.name} has no example that runs")


def test_the_cli_reference_is_every_commands_help():
    """docs/hooks.py renders ``drivecal --help`` and each command's help into docs/cli.md at build time."""
    import importlib.util

    import click

    from drivecal.cli import cli

    spec = importlib.util.spec_from_file_location("docs_hooks", ROOT / "docs" / "hooks.py")
    hooks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hooks)
    page = (ROOT / "docs" / "cli.md").read_text(encoding="utf-8")
    assert hooks.MARKER in page
    rendered = hooks.on_page_markdown(page, None, None, None)
    assert hooks.MARKER not in rendered and "$ drivecal --help" in rendered
    sections = rendered.split("\n## ")
    ctx = click.Context(cli, info_name="drivecal")
    names = cli.list_commands(ctx)
    assert len(names) >= 10
    for name in names:
        section = next(s for s in sections if s.startswith(f"`drivecal {name}`"))
        command = cli.get_command(ctx, name)
        assert f"Usage: drivecal {name} " in section
        for param in command.params:
            for opt in param.opts if isinstance(param, click.Option) else ():
                assert opt in section, (name, opt)


def github_slug(heading: str) -> str:
    """A heading's anchor as GitHub makes it, and the site too (mkdocs.yml's pymdownx slugify)."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def anchors(page: Path) -> set[str]:
    found, fence = set(), False
    for line in page.read_text(encoding="utf-8").split("\n"):
        if FENCE.match(line):
            fence = not fence
        elif not fence and (m := re.match(r"^#{1,6} (.*)$", line)):
            found.add(github_slug(m.group(1)))
    return found


def test_the_readmes_links_reach_pages_and_anchors():
    """The README is not part of the site (mkdocs checks the pages' links): its relative links checked here."""
    readme = ROOT / "README.md"
    links = re.findall(r"\]\(([^)\s]+)\)", readme.read_text(encoding="utf-8"))
    relative = [link for link in links if not re.match(r"^[a-z]+:", link)]
    assert len(relative) >= 10
    for link in relative:
        path, _, anchor = link.partition("#")
        target = (ROOT / path) if path else readme
        assert target.exists(), f"README.md links to {link}: no such file"
        if anchor:
            assert anchor in anchors(target), f"README.md links to {link}: no such anchor in {path}"
