#!/usr/bin/env python3
"""Runs every shell and Python block of README.md, in order, in one shell.

Usage: python3 tests/readme_blocks.py SEMDEPTH_BINARY

The blocks run in a scratch copy of the repository's examples/ (so nothing
lands in the tree) with ../shared beside it, as a new user at the repository
root would paste them. Adaptations, each what a user would get anyway:
- `semdepth` is the given binary (on PATH), `cargo install --locked --path .`
  is then a no-op and `cargo run --release -- ARGS` is `semdepth ARGS`: the
  same code, built once by CI instead of once per block;
- a block marked `<!-- readme-test: background -->` (the foreground server
  of "Run it") runs in the background until the end, and the next block waits
  for its /readyz;
- a block marked `<!-- readme-test: skip REASON -->` is not run (the
  container, covered by tests/container/smoke.sh; the test commands, which
  CI runs itself).
Any failing command fails the run (bash -e), naming the block.
"""

import os
import pathlib
import re
import shutil
import subprocess
import sys
import tempfile

ROOT = pathlib.Path(__file__).resolve().parent.parent
FENCE = re.compile(r"^```(\w*)\s*$")
MARK = re.compile(r"^<!-- readme-test: (skip|background)\b(.*)-->\s*$")


def blocks(text):
    """(line, language, code, mark) of each fenced block, in order."""
    lines = text.splitlines()
    out = []
    i = 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        start, lang = i, m.group(1)
        j = i + 1
        while j < len(lines) and not lines[j].startswith("```"):
            j += 1
        k = start - 1
        while k >= 0 and not lines[k].strip():
            k -= 1
        mark = MARK.match(lines[k]) if k >= 0 else None
        out.append((start + 1, lang, "\n".join(lines[start + 1 : j]), mark.group(1) if mark else None))
        i = j + 1
    return out


PRELUDE = r"""
set -eo pipefail
# The streaming example says `pip install websockets`.
python3 -c 'import websockets' 2>/dev/null || python3 -m pip install --quiet --disable-pip-version-check websockets
cargo() {
    case "$*" in
        "install --locked --path ."*) echo "(readme test: semdepth is already on PATH)" ;;
        "run --release -- "*) shift 3; semdepth "$@" ;;
        *) command cargo "$@" ;;
    esac
}
wait_ready() {
    for _ in $(seq 300); do
        curl -sf "$1/readyz" >/dev/null 2>&1 && return 0
        sleep 0.1
    done
    echo "no /readyz at $1 within 30 s" >&2; cat "$2" >&2; return 1
}
"""


def script(readme):
    parts = [PRELUDE]
    for line, lang, code, mark in blocks(readme):
        if lang not in ("sh", "python") or mark == "skip":
            continue
        parts.append(f"echo; echo '== README.md line {line} ({lang})'")
        if mark == "background":
            # Not a job of this shell: `kill %1` in a later block means that block's own.
            parts.append(f"( {code.strip()} > background-{line}.log 2>&1 & echo $! > background.pid )")
            parts.append(f"wait_ready http://127.0.0.1:8080 background-{line}.log")
        elif lang == "sh":
            parts.append(code)
        else:
            parts.append(f"python3 - <<'README_PYTHON'\n{code}\nREADME_PYTHON")
    return "\n".join(parts) + "\n"


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    binary = pathlib.Path(sys.argv[1]).resolve()
    if not os.access(binary, os.X_OK):
        sys.exit(f"not an executable: {binary}")
    text = (ROOT / "README.md").read_text()
    work = pathlib.Path(tempfile.mkdtemp(prefix="readme-"))
    repo = work / "main"
    try:
        repo.mkdir()
        shutil.copytree(ROOT / "examples", repo / "examples")
        (work / "shared").symlink_to(ROOT.parent / "shared")
        bindir = work / "bin"
        bindir.mkdir()
        (bindir / "semdepth").symlink_to(binary)
        (repo / "readme.sh").write_text(script(text))
        env = dict(os.environ, PATH=f"{bindir}:{os.environ['PATH']}")
        run = subprocess.run(["bash", "readme.sh"], cwd=repo, env=env)
        status = run.returncode
    finally:
        pid = repo / "background.pid"
        if pid.exists():
            # The subshell and the server it runs (a child: `cargo` is a function).
            subprocess.run(["pkill", "-TERM", "-P", pid.read_text().strip()], check=False)
            subprocess.run(["kill", pid.read_text().strip()], check=False)
        shutil.rmtree(work, ignore_errors=True)
    print(f"README blocks: {'all ran' if status == 0 else f'failed (exit {status})'}")
    sys.exit(status)


if __name__ == "__main__":
    main()
