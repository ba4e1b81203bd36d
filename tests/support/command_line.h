// Test helpers for the command line tools: run one and collect its exit status and standard error.
#pragma once
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "scratch_dir.h"

namespace cip::test {

inline std::string slurp(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

struct CommandResult {
  int status;
  std::string err;
};

/// Runs a shell command line, standard output discarded (standard error goes through a file in a scratch
/// folder of its own).
inline CommandResult run(const std::string& args) {
  ScratchDir scratch;
  const std::string errFile = scratch.file("stderr.txt");
  int rc = std::system((args + " 2> '" + errFile + "' > /dev/null").c_str());
  return {WEXITSTATUS(rc), slurp(errFile)};
}

}  // namespace cip::test
