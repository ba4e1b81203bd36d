#!/usr/bin/env python3
"""Checks that the measured figures in docs/method.md and README.md are what the code produces.

The docs' measured tables are generated blocks:

    <!-- generated: cip_bench method --table analytic -->
    | header | ... |
    |---|...|
    | rows ... |
    <!-- end generated -->

The comment holds the `cip_bench method` arguments whose output the block is (`--rows` may pick cases, see
`cip_bench method --help`). benchmarks/results/method-tables.md records that output for every block: `--record`
writes it and the blocks together from one full run, so the two always agree, and a hand edit of either shows.

Modes:

- default (CI, `.ci/run`; about a minute on 2 cores): runs `cip_bench method --single-build` for the cheap cases
  (CI_ROWS: the analytic fields at N = 32 and the nucleon) and compares every column of those rows with the docs
  except the times, whose format alone is checked (times differ between runs and machines). The other rows
  (N = 64, the tooth, headsq, the OpenVDB volumes: about 20 minutes on 2 cores) are compared with the recorded
  output only; `--full` regenerates them too. Then it checks that each block equals its recorded output, and
  the figures the prose of the README and method.md quotes from the tables (`derived` below).
- `--recorded-only` (ctest, no cip_bench needed): the last two checks only.
- `--full`: as the default, with every row regenerated.
- `--record`: runs the full timed `cip_bench method` for every block (about 40 minutes on 2 cores), writes
  benchmarks/results/method-tables.md and rewrites the blocks in the docs from it. `--from FILE` takes the
  outputs from a results file instead of running cip_bench.
- `--self-test`: plants a wrong figure, a wrong derived figure and a broken marker in copies of the docs and
  expects each found (ctest).

Not checked: the times (format only), the rows of the slow cases between full runs (against the recorded output
only), figures in the prose other than those of `derived` (many describe earlier versions of the code and
experiments that the current code does not rerun), and the hand-made summary table of `auto`'s choices in
method.md.
"""
import argparse
import concurrent.futures
import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DOCS = ["docs/method.md", "README.md"]
RESULTS = "benchmarks/results/method-tables.md"
# The cases CI regenerates: every table's rows of N = 32 and of the nucleon (about a minute in all).
CI_ROWS = r"^(sphere|torus|gyroid|marschner-lobb) 32|^nucleon"
BEGIN = re.compile(r"^\s*<!-- generated: cip_bench method (.*?) -->$")
END = "<!-- end generated -->"
NUMBER = re.compile(r"[-+]?\d+(\.\d+)?")


class Block:
    def __init__(self, doc, args, first, last, lines):
        self.doc, self.args, self.first, self.last, self.lines = doc, args, first, last, lines

    def where(self):
        return f"{self.doc}:{self.first + 1} (cip_bench method {self.args})"


def read(root, path):
    with open(os.path.join(root, path), encoding="utf-8") as f:
        return f.read().split("\n")


def find_blocks(root, problems):
    blocks = []
    for doc in DOCS:
        lines = read(root, doc)
        i = 0
        while i < len(lines):
            m = BEGIN.match(lines[i])
            if not m:
                if lines[i].strip().startswith("<!-- generated") or lines[i].strip() == END:
                    problems.append(f"{doc}:{i + 1}: a marker outside the form '<!-- generated: cip_bench method "
                                    f"ARGS -->' ... '{END}'")
                i += 1
                continue
            j = i + 1
            while j < len(lines) and lines[j].strip() != END and not BEGIN.match(lines[j]):
                j += 1
            if j == len(lines) or lines[j].strip() != END:
                problems.append(f"{doc}:{i + 1}: generated block without '{END}'")
                i = j
                continue
            blocks.append(Block(doc, m.group(1).strip(), i, j, lines[i + 1:j]))
            i = j + 1
    return blocks


def cells(line):
    return [c.strip() for c in line.strip().strip("|").split("|")]


def table(lines):
    """(header cells, {first cell: row cells}) of the Markdown table in `lines` (blank lines ignored)."""
    rows = [l.strip() for l in lines if l.strip()]
    if len(rows) < 2 or not all(l.startswith("|") for l in rows):
        raise ValueError("not a Markdown table")
    header, body = cells(rows[0]), {}
    for l in rows[2:]:
        c = cells(l)
        if len(c) != len(header):
            raise ValueError(f"row '{c[0]}' has {len(c)} cells, the header {len(header)}")
        if c[0] in body:
            raise ValueError(f"row '{c[0]}' twice")
        body[c[0]] = c
    return header, body


def shape(cell):
    """A time cell with its numbers replaced: "5.2 → 13.6 ms (2.6×)" -> "# → # ms (#×)"."""
    return NUMBER.sub("#", cell)


def compare(where, expected, actual, source, problems, all_rows=True):
    """Rows of `actual` (the docs) against `expected` (generated or recorded): every column but the times, whose
    format alone must agree. With all_rows, both must have the same rows; else every expected row must be in
    the docs."""
    (eh, erows), (ah, arows) = expected, actual
    if eh != ah:
        problems.append(f"{where}: the header differs from {source}:\n  docs: {' | '.join(ah)}\n  "
                        f"{source}: {' | '.join(eh)}")
        return 0
    timed = [k for k, h in enumerate(eh) if "time" in h.lower()]
    for key, row in erows.items():
        if key not in arows:
            problems.append(f"{where}: row '{key}' of {source} is missing")
            continue
        for k, (e, a) in enumerate(zip(row, arows[key])):
            if (shape(e) != shape(a)) if k in timed else (e != a):
                problems.append(f"{where}: row '{key}', column '{eh[k]}': the docs say '{a}', {source} "
                                f"'{e}'")
    if all_rows:
        for key in arows:
            if key not in erows:
                problems.append(f"{where}: row '{key}' is not in {source}")
    return len(erows)


def run_bench(bench, shared, args, extra):
    cmd = [bench, "method", *shlex.split(args), "--shared-data", shared, *extra]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(map(shlex.quote, cmd))} failed ({r.returncode}): {r.stderr.strip()}")
    return r.stdout


def load_results(path):
    """{block arguments: output lines} from a results file."""
    out, current = {}, None
    with open(path, encoding="utf-8") as f:
        for line in f.read().split("\n"):
            m = re.match(r"^## cip_bench method (.*)$", line)
            if m:
                current = m.group(1).strip()
                out[current] = []
            elif current is not None:
                out[current].append(line)
    return {k: [l for l in v if l.startswith("|")] for k, v in out.items()}


def write_results(path, outputs):
    with open(path, "w", encoding="utf-8") as f:
        f.write("# The measured tables of docs/method.md, as `cip_bench method` printed them\n\n"
                "`python3 benchmarks/doc_figures.py --record` writes it and the generated blocks of the docs "
                "together (one full,\ntimed run of `cip_bench method --shared-data ../shared/data` per block); "
                "`benchmarks/doc_figures.py` checks\nthat the docs show exactly this, and CI regenerates the "
                "rows of the small cases.\n")
        for args, lines in outputs.items():
            f.write(f"\n## cip_bench method {args}\n\n" + "\n".join(l for l in lines if l.strip()) + "\n")


def pct(cell):
    """The percentage in a cell such as '**12 (0.03 %)**'."""
    return float(re.search(r"\(([\d.]+) %\)", cell).group(1))


def derived(tables, root):
    """(doc, expected text) for the figures the prose quotes: each is computed from the tables (checked above)
    or from the code, and must appear as written (line breaks and indentation aside)."""
    leaks = tables["--table open-faces"][1]
    real = [pct(r[3]) for k, r in leaks.items() if re.match(r"^(nucleon|tooth|headsq|vdb/)", k)]
    ml = [pct(r[3]) for k, r in leaks.items() if k.startswith("marschner-lobb")]
    header = open(os.path.join(root, "libcip/cip/reference/reconstruction_choice.h"), encoding="utf-8").read()
    wavelength = re.search(r"kCentral8Wavelength\s*=\s*([\d.]+)", header).group(1)
    return [
        ("README.md", f"{min(real):g}–{max(real):.2f} % of the cells on the real volumes are left with one, "
                      f"and up to {max(ml):.0f} %"),
        ("README.md", f"(an effective wavelength of at least {wavelength} samples)"),
        ("docs/method.md", f"in at most {max(real):.2f} % of the cells of the real volumes"),
        ("docs/method.md", f"Marschner–Lobb ({pct(leaks['marschner-lobb 64 gradient'][3]):.1f} % of the cells "
                           f"at N = 64, {pct(leaks['marschner-lobb 32 exact'][3]):.0f} % at N = 32 in exact mode"),
    ]


def check(root, bench, shared, full, recorded_only):
    problems = []
    blocks = find_blocks(root, problems)
    doc_tables = {}
    for b in blocks:
        try:
            doc_tables[b.args] = table(b.lines)
        except ValueError as e:
            problems.append(f"{b.where()}: {e}")
    recorded = load_results(os.path.join(root, RESULTS))
    for b in blocks:
        if b.args not in recorded:
            problems.append(f"{b.where()}: no output recorded in {RESULTS}")
        elif b.args in doc_tables:
            compare(b.where(), table(recorded[b.args]), doc_tables[b.args], RESULTS, problems)
    for args in recorded:
        if args not in doc_tables:
            problems.append(f"{RESULTS}: 'cip_bench method {args}' is recorded but no doc has its block")
    regenerated = 0
    if not recorded_only:
        extra = ["--single-build"] + ([] if full else ["--rows", CI_ROWS])
        todo = [b for b in blocks if b.args in doc_tables]
        with concurrent.futures.ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
            outputs = list(pool.map(lambda b: run_bench(bench, shared, b.args, extra), todo))
        for b, out in zip(todo, outputs):
            regenerated += compare(b.where(), table(out.split("\n")), doc_tables[b.args], "cip_bench", problems,
                                   all_rows=full)
    if "--table open-faces" in doc_tables:
        for doc, text in derived(doc_tables, root):
            if text not in " ".join(" ".join(read(root, doc)).split()):
                problems.append(f"{doc}: does not say '{text}' (computed from the tables and the code)")
    else:
        problems.append("no block 'cip_bench method --table open-faces', which the derived figures need")
    rows = sum(len(t[1]) for t in doc_tables.values())
    what = "recorded output only" if recorded_only else \
        f"{regenerated} rows regenerated ({'all' if full else 'cases ' + CI_ROWS}), the rest against {RESULTS}"
    return problems, f"{len(blocks)} generated blocks, {rows} rows: {what}"


def record(root, bench, shared, source):
    problems = []
    blocks = find_blocks(root, problems)
    if problems:
        return problems
    args = list(dict.fromkeys(b.args for b in blocks))
    if source:
        have = load_results(source)
        outputs = {a: have[a] for a in args if a in have}
        problems += [f"{source}: no output for 'cip_bench method {a}'" for a in args if a not in have]
    else:
        outputs = {a: run_bench(bench, shared, a, []).split("\n") for a in args}
    if problems:
        return problems
    write_results(os.path.join(root, RESULTS), outputs)
    for doc in DOCS:
        lines = read(root, doc)
        for b in sorted((b for b in blocks if b.doc == doc), key=lambda b: -b.first):
            indent = re.match(r"\s*", lines[b.first]).group(0)  # a table inside a list item
            lines[b.first + 1:b.last] = [indent + l.strip() for l in outputs[b.args] if l.strip()]
        with open(os.path.join(root, doc), "w", encoding="utf-8") as f:
            f.write("\n".join(lines))
    return []


def self_test():
    """Plants one fault of each kind in a copy of the docs and expects the recorded-output check to find it."""
    # A time cell's ratio, whichever the last recording gave ("(2.6×) |" at the end of a row).
    method = open(os.path.join(ROOT, "docs/method.md"), encoding="utf-8").read()
    match = re.search(r"\(\d+(\.\d+)?×\) \|\n", method)
    first_time_cell = match.group(0) if match else "(no time cell in docs/method.md)"
    faults = [
        ("docs/method.md", "| torus 32 gradient | 2040 | 296 (14.51 %) | **0 (0.00 %)** |",
         "| torus 32 gradient | 2040 | 296 (14.52 %) | **0 (0.00 %)** |", "column 'paper: cells leaking"),
        ("docs/method.md", "| tooth.nhdr 120 | 63928 |", "| tooth.nhdr 120 | 63929 |", "'63929'"),
        ("docs/method.md", "| 32, exact: fitted | 3.67 |", "| 32, exact: fitted | 3.66 |", "'3.66'"),
        ("docs/method.md", first_time_cell, first_time_cell.replace("×)", " times)"), "column 'time paper"),
        ("docs/method.md", "| sphere 32, central8 |", "| sphere 33, central8 |", "row 'sphere 32, central8'"),
        ("README.md", "up to 18 %", "up to 19 %", "README.md: does not say"),
        ("docs/method.md", END, "<!-- end -->", "without '<!-- end generated -->'"),
    ]
    with tempfile.TemporaryDirectory() as tmp:
        for rel in DOCS + [RESULTS, "libcip/cip/reference/reconstruction_choice.h"]:
            os.makedirs(os.path.dirname(os.path.join(tmp, rel)) or tmp, exist_ok=True)
            shutil.copy(os.path.join(ROOT, rel), os.path.join(tmp, rel))
        problems, _ = check(tmp, None, None, False, True)
        if problems:
            print("self-test: the unplanted copy is not clean:\n" + "\n".join(problems))
            return 1
        for doc, old, new, expect in faults:
            path = os.path.join(tmp, doc)
            text = open(path, encoding="utf-8").read()
            if old not in text:
                print(f"self-test: '{old}' not in {doc}; update the self-test")
                return 1
            open(path, "w", encoding="utf-8").write(text.replace(old, new, 1))
            problems, _ = check(tmp, None, None, False, True)
            open(path, "w", encoding="utf-8").write(text)
            if not any(expect in p for p in problems):
                print(f"self-test: planting '{new}' in {doc} was not reported as '{expect}':\n" +
                      "\n".join(problems))
                return 1
        # --record from the recorded output rewrites the blocks as they are.
        before = {d: open(os.path.join(tmp, d), encoding="utf-8").read() for d in DOCS}
        if record(tmp, None, None, os.path.join(ROOT, RESULTS)):
            print("self-test: --record --from failed")
            return 1
        for d in DOCS:
            if open(os.path.join(tmp, d), encoding="utf-8").read() != before[d]:
                print(f"self-test: --record --from the recorded output changed {d}")
                return 1
    print(f"self-test: {len(faults)} planted faults found")
    return 0


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bench", default=os.path.join(ROOT, "build", "benchmarks", "cip_bench"))
    ap.add_argument("--shared-data", default=os.path.join(ROOT, "..", "shared", "data"))
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument("--full", action="store_true", help="regenerate every row (about 20 minutes on 2 cores)")
    mode.add_argument("--recorded-only", action="store_true", help="do not run cip_bench")
    mode.add_argument("--record", action="store_true", help="measure again and rewrite the results and blocks")
    mode.add_argument("--self-test", action="store_true")
    ap.add_argument("--from", dest="source", help="with --record: take the outputs from this results file")
    args = ap.parse_args()
    if args.self_test:
        return self_test()
    needs_bench = not args.recorded_only and not (args.record and args.source)
    if needs_bench and not os.access(args.bench, os.X_OK):
        print(f"doc_figures: {args.bench} not found; build with -DCIP_BUILD_BENCHMARKS=ON", file=sys.stderr)
        return 2
    if args.record:
        problems = record(ROOT, args.bench, args.shared_data, args.source)
        summary = f"wrote {RESULTS} and the generated blocks"
    else:
        problems, summary = check(ROOT, args.bench, args.shared_data, args.full, args.recorded_only)
    for p in problems:
        print("doc_figures: " + p, file=sys.stderr)
    print(f"doc_figures: {summary}: {'FAILED, ' + str(len(problems)) + ' problems' if problems else 'ok'}")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
