"""Re-run a docs page's examples as tests/test_docs.py does and re-paste mismatched command outputs.

usage: repaste.py PAGE [--write]   (run from the repo root; COLUMNS=120)
"""
import os, sys, shutil, tempfile, io, contextlib, shlex, subprocess
from pathlib import Path
ROOT = Path.cwd()
sys.path.insert(0, str(ROOT / "tests"))
os.environ.setdefault("COLUMNS", "120")
import test_docs as td

page = ROOT / sys.argv[1]
write = "--write" in sys.argv
lines = page.read_text().splitlines()
tmp = Path(tempfile.mkdtemp())
shutil.copytree(ROOT / "examples", tmp / "examples")
os.chdir(tmp)
ns = {"__name__": "__docs__"}
edits = []  # (start_line_index, end_line_index, new_lines)
for block in td.blocks(page):
    where = f"{page.name}:{block.line}"
    if block.file:
        (tmp / block.file).parent.mkdir(parents=True, exist_ok=True)
        (tmp / block.file).write_text(block.text + "\n")
        continue
    if not td._runnable(block) or block.skip is not None:
        continue
    if block.lang == "python":
        try:
            td.run_python(block, where, ns)
        except AssertionError as e:
            print("PYTHON MISMATCH", where, str(e)[:3000])
        continue
    for cmd in td.commands(block):
        try:
            td.run_command(cmd, where)
            continue
        except AssertionError as e:
            msg = str(e)
        printed = msg.split("--- printed:\n", 1)[1] if "--- printed:\n" in msg else msg.split("\n", 1)[1]
        status_bad = "exit status" in msg.splitlines()[0]
        print("MISMATCH", f"{page.name}:{cmd.line}", msg.splitlines()[0][:300])
        if status_bad:
            print("  (exit status differs: fix by hand)"); print(printed[:2000]); continue
        if any(l.strip() == "..." for l in cmd.expected):
            print("  (has ... elision: fix by hand)"); print(printed); continue
        # the command's line in the page is cmd.line (1-based, the $ line); expected lines follow
        i0 = cmd.line  # index of first expected line (0-based = cmd.line)
        # command may continue with backslashes
        j = cmd.line - 1
        while lines[j].rstrip().endswith("\\"):
            j += 1
        start = j + 1
        if "; echo $?" in " ".join(lines[cmd.line - 1:j + 1]):
            start += 1
        end = start
        while end < len(lines) and not lines[end].lstrip().startswith("$ ") and not lines[end].lstrip().startswith("```"):
            end += 1
        new = [l.rstrip() for l in printed.rstrip("\n").split("\n")]
        while new and not new[-1].strip():
            new.pop()
        new = [l for l in new if True]
        # drop blank line separating stdout/stderr when stderr empty
        edits.append((start, end, new))
if write and edits:
    for start, end, new in sorted(edits, reverse=True):
        lines[start:end] = new
    page.write_text("\n".join(lines) + "\n")
    print("wrote", len(edits), "edits to", page)
