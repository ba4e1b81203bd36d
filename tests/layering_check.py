#!/usr/bin/env python3
"""Checks that libcip's folders stay a stack of stages and its functions stay short.

- Stages, bottom to top: a file in libcip/cip/<stage>/ includes "cip/<other>/..." only for <other> at or below
  <stage>, so the folder-level include graph has no cycle. Every included cip header exists.
- libcip includes no Embree, OpenImageIO, OpenEXR or libpng header, and OpenVDB and GDCM headers only in
  libcip/cip/modules/ (the code of the shared objects libcip loads on first use, core/module_loader.h).
- No stage folder holds more than MAX_FILES source files.
- No function in libcip, extract or raycast is longer than MAX_LINES lines (a definition that starts at column 0
  up to its closing brace, lambdas inside it included).

    python3 tests/layering_check.py [--root DIR]     # exit 1 and one line per finding when the layout breaks
    python3 tests/layering_check.py --self-test      # plants each kind of finding in a copy and expects it caught
"""
import argparse
import os
import re
import shutil
import sys
import tempfile

STAGES = ["core", "topology", "volume", "readers", "modules", "reference", "patch", "ray", "model", "mesh", "meshio",
          "measure"]
# readers/ holds a header and source per file format: nine formats and their plumbing; core/ the vocabulary and
# the process's plumbing (files, memory, threads and ranks, modules)
MAX_FILES = 22
MAX_LINES = 150
INCLUDE = re.compile(r'^\s*#\s*include\s*[<"]([^>"]+)[>"]', re.M)
FORBIDDEN_IN_CORE = ("embree", "OpenImageIO", "OpenEXR", "png.h")
FUNCTION_START = re.compile(r"^(?!namespace|struct|class|enum|union|#|//|\}|using|static_assert|template\s*<.*>\s*$)"
                            r"[A-Za-z_].*\(")


def source_files(folder):
    for dirpath, _, names in os.walk(folder):
        for name in sorted(names):
            if name.endswith((".h", ".cpp")):
                yield os.path.join(dirpath, name)


def layering_findings(root):
    cip = os.path.join(root, "libcip", "cip")
    findings = []
    loose = [n for n in os.listdir(cip) if os.path.isfile(os.path.join(cip, n))]
    findings += ["libcip/cip/%s: every file belongs to a stage folder" % n for n in loose]
    for name in sorted(os.listdir(cip)):
        if os.path.isdir(os.path.join(cip, name)) and name not in STAGES:
            findings.append("libcip/cip/%s/: not a stage (known: %s)" % (name, ", ".join(STAGES)))
    for stage in STAGES:
        folder = os.path.join(cip, stage)
        if not os.path.isdir(folder):
            continue
        files = list(source_files(folder))
        if len(files) > MAX_FILES:
            findings.append("libcip/cip/%s/: %d source files (at most %d)" % (stage, len(files), MAX_FILES))
        for path in files:
            rel = os.path.relpath(path, root)
            text = open(path, encoding="utf-8").read()
            for header in INCLUDE.findall(text):
                if header.startswith("cip/"):
                    parts = header.split("/")
                    if len(parts) != 3 or parts[1] not in STAGES:
                        findings.append("%s: includes %s, which is in no stage folder" % (rel, header))
                        continue
                    if not os.path.exists(os.path.join(root, "libcip", header)):
                        findings.append("%s: includes %s, which does not exist" % (rel, header))
                    if STAGES.index(parts[1]) > STAGES.index(stage):
                        findings.append("%s: %s/ includes %s from %s/, a later stage" % (rel, stage, header,
                                                                                         parts[1]))
                elif header.startswith(FORBIDDEN_IN_CORE):
                    findings.append("%s: includes %s (Embree and the image libraries stay out of libcip)" % (rel, header))
                elif header.startswith(("openvdb/", "gdcm")) and stage != "modules":
                    findings.append("%s: includes %s outside libcip/cip/modules/ (OpenVDB and GDCM are loaded on "
                                    "first use, in modules)" % (rel, header))
    return findings


def long_functions(path, limit):
    lines = open(path, encoding="utf-8").read().split("\n")
    found, i = [], 0
    while i < len(lines):
        if FUNCTION_START.match(lines[i]):
            k = i  # the signature may span lines: its body opens where a line ends with '{'
            while k < len(lines) and k - i < 10 and not lines[k].rstrip().endswith(("{", ";")):
                k += 1
            if k < len(lines) and lines[k].rstrip().endswith("{"):
                depth = 0
                for m in range(k, len(lines)):
                    depth += lines[m].count("{") - lines[m].count("}")
                    if depth == 0:
                        break
                if m - i + 1 > limit:
                    found.append((i + 1, m - i + 1, lines[i].strip()[:60]))
                i = m + 1
                continue
        i += 1
    return found


def length_findings(root):
    findings = []
    for top in ("libcip", "extract", "raycast"):
        for path in source_files(os.path.join(root, top)):
            if path.endswith(".cpp"):
                for line, count, text in long_functions(path, MAX_LINES):
                    findings.append("%s:%d: %d lines (at most %d): %s" % (os.path.relpath(path, root), line, count,
                                                                         MAX_LINES, text))
    return findings


def check(root):
    return layering_findings(root) + length_findings(root)


def self_test(root):
    """Each planted defect must be found, and the unplanted copy must be clean."""
    plants = {
        "wrong-way include": ("libcip/cip/core/planted.h", '#include "cip/model/model.h"\n'),
        "missing header": ("libcip/cip/model/planted.h", '#include "cip/model/no_such_header.h"\n'),
        "folder outside the stages": ("libcip/cip/misc/planted.h", "\n"),
        "loose file": ("libcip/cip/planted.h", "\n"),
        "Embree in libcip": ("libcip/cip/mesh/planted.h", "#include <embree3/rtcore.h>\n"),
        "OpenVDB outside the modules": ("libcip/cip/readers/planted.cpp", "#include <openvdb/openvdb.h>\n"),
        "GDCM outside the modules": ("libcip/cip/readers/planted.cpp", "#include <gdcmReader.h>\n"),
        "long function": ("extract/planted.cpp",
                          "int planted(int x) {\n" + "  x += 1;\n" * MAX_LINES + "  return x;\n}\n"),
        "crowded folder": ("libcip/cip/topology/", None),
    }
    failures = 0
    for name, (rel, text) in plants.items():
        with tempfile.TemporaryDirectory() as tmp:
            for top in ("libcip", "extract", "raycast"):
                shutil.copytree(os.path.join(root, top), os.path.join(tmp, top))
            if not check(tmp) == []:
                print("self-test: the unplanted copy is not clean", file=sys.stderr)
                return 1
            if text is None:
                for n in range(MAX_FILES + 1):
                    open(os.path.join(tmp, rel, "planted%d.h" % n), "w").write("\n")
            else:
                os.makedirs(os.path.dirname(os.path.join(tmp, rel)), exist_ok=True)
                open(os.path.join(tmp, rel), "w").write(text)
            caught = check(tmp)
            print("self-test: %s: %s" % (name, "caught" if caught else "NOT CAUGHT"))
            failures += not caught
    return 1 if failures else 0


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", default=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    ap.add_argument("--self-test", action="store_true")
    args = ap.parse_args()
    if args.self_test:
        sys.exit(self_test(args.root))
    findings = check(args.root)
    for f in findings:
        print(f)
    print("layering check: %d finding(s)" % len(findings))
    sys.exit(1 if findings else 0)


if __name__ == "__main__":
    main()
