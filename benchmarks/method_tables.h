// The measured tables of docs/method.md: `cip_bench method [--quick] [--shared-data DIR] [--table NAME]...
// [--single-build] [--rows REGEX]...` prints them as Markdown, every row from builds made side by side in the
// same run.
#pragma once
#include <string>
#include <vector>

namespace cipbench {

/// The names of the tables, in the order they are printed: analytic, real, reconstruction, aliasing,
/// open-faces.
const std::vector<std::string>& methodTableNames();

struct MethodTableOptions {
  std::string sharedData = "../shared/data";
  bool quick = false;               ///< N = 16 and the nucleon only
  std::vector<std::string> tables;  ///< names from methodTableNames(); empty: all
  /// Build each model once instead of best of 5-25 timed rounds: the same models and figures, the times
  /// then of a single build (benchmarks/doc_figures.py checks the docs' figures this way and ignores the
  /// times).
  bool singleBuild = false;
  /// Only the cases whose name every (ECMAScript) regular expression finds: "torus 32 gradient" (analytic and
  /// open-faces tables), "headsq.nhdr 1150" (real volumes), "torus 32", "nucleon.nhdr 128"
  /// (reconstruction), "marschner-lobb 32" (aliasing); empty: all.
  std::vector<std::string> rows;
};

/// Prints the tables asked for; throws cip::Error for an unknown table name.
void methodTables(const MethodTableOptions& options);

}  // namespace cipbench
