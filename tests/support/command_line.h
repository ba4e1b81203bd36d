// Test helpers for the command line tools: run one and collect its exit status and standard error.
#pragma once
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

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

/// Runs a shell command line, standard output discarded.
inline CommandResult run(const std::string& args) {
  std::filesystem::path errFile =
      std::filesystem::temp_directory_path() / ("cip_cli_stderr_" + std::to_string(::getpid()) + ".txt");
  int rc = std::system((args + " 2> " + errFile.string() + " > /dev/null").c_str());
  std::string err = slurp(errFile);
  std::filesystem::remove(errFile);
  return {WEXITSTATUS(rc), err};
}

}  // namespace cip::test
