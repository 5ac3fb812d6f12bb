"""Lines of code of the pipeline, the log and teleop, before the one-pipeline redesign and now.

Run: ``python benchmarks/bench_loc.py [--before REV]`` (needs the git history). Counts, per
group of files, all lines and code lines (not blank, not a comment, not inside a docstring).
``--before`` defaults to ``bb4f4cf``, main before the work on issue 14 (one pipeline) began.
"""

from __future__ import annotations

import argparse
import ast
import io
import subprocess
import tokenize
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SRC = "src/motionbase/"

#: The groups the issue names; a file missing at a revision counts 0.
GROUPS = {
    "pipeline (loop, stages, plug-in interfaces)": [
        "pipeline.py",
        "stages.py",
        "washout/cueing.py",
        "platform/robot.py",
    ],
    "log (MCAP writer, pipeline log)": [
        "io/mcap_log.py",
        "io/log_writer.py",
        "io/_log_kernels.py",
        "io/pipeline_log.py",
        "tick_record.py",  # the pipeline log's messages, made in the writer process
    ],
    "teleop, motor outputs and the wiring check": [
        "teleop.py",
        "commanding.py",
        "io/motor_output.py",
    ],
}


def _text(rev: str | None, path: str) -> str | None:
    if rev is None:
        p = ROOT / path
        return p.read_text() if p.exists() else None
    out = subprocess.run(
        ["git", "-C", str(ROOT), "show", f"{rev}:{path}"], capture_output=True, text=True
    )
    return out.stdout if out.returncode == 0 else None


def count(source: str) -> tuple[int, int]:
    """(all lines, code lines) of a Python source."""
    doc_lines: set[int] = set()
    for node in ast.walk(ast.parse(source)):
        body = getattr(node, "body", None)
        if isinstance(body, list) and body and isinstance(body[0], ast.Expr):
            value = body[0].value
            if isinstance(value, ast.Constant) and isinstance(value.value, str):
                doc_lines.update(range(body[0].lineno, body[0].end_lineno + 1))
    code: set[int] = set()
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type in (tokenize.COMMENT, tokenize.NL, tokenize.NEWLINE, tokenize.INDENT):
            continue
        if tok.type in (tokenize.DEDENT, tokenize.ENDMARKER):
            continue
        for line in range(tok.start[0], tok.end[0] + 1):
            if line not in doc_lines:
                code.add(line)
    return len(source.splitlines()), len(code)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", default="bb4f4cf", help="git revision before the redesign")
    args = parser.parse_args()
    print(f"lines of code (all / code), {args.before} -> working tree")
    totals = [0, 0, 0, 0]
    for group, files in GROUPS.items():
        row = [0, 0, 0, 0]
        lines = []
        for name in files:
            one = [0, 0, 0, 0]
            for k, rev in enumerate((args.before, None)):
                text = _text(rev, SRC + name)
                if text is not None:
                    one[2 * k], one[2 * k + 1] = count(text)
            row = [a + b for a, b in zip(row, one, strict=True)]
            lines.append(f"    {name:43s} {one[0]:5d} / {one[1]:5d}  ->  {one[2]:5d} / {one[3]:5d}")
        totals = [a + b for a, b in zip(totals, row, strict=True)]
        print(f"  {group:45s} {row[0]:5d} / {row[1]:5d}  ->  {row[2]:5d} / {row[3]:5d}")
        print("\n".join(lines))
    print(
        f"  {'total':45s} {totals[0]:5d} / {totals[1]:5d}  ->  {totals[2]:5d} / {totals[3]:5d}"
        f"  ({totals[3] - totals[1]:+d} code lines)"
    )


if __name__ == "__main__":
    main()
