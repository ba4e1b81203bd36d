// Replays fuzz inputs without libFuzzer: every file of the corpus folder, of the regression folders and every
// file named on the command line is fed to LLVMFuzzerTestOneInput once. CTest runs this over the seed corpora
// and the regression inputs. A corpus folder that is missing or holds no input, or a regression folder or
// file that is missing, is an error (exit status 2): a replay that found nothing to replay must not pass.
//
//   fuzz_replay_X --corpus DIR [--regressions DIR]... [FILE]...
#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size);

namespace {

namespace fs = std::filesystem;

/// The inputs in a folder, sorted; hidden files (.keep, which holds an empty folder in git) are not inputs.
std::vector<fs::path> inputsIn(const fs::path& dir) {
  std::vector<fs::path> inputs;
  for (const auto& e : fs::directory_iterator(dir))
    if (e.is_regular_file() && e.path().filename().string().rfind('.', 0) != 0) inputs.push_back(e.path());
  std::sort(inputs.begin(), inputs.end());
  return inputs;
}

int usage(const char* program, const std::string& problem) {
  std::fprintf(stderr, "%s: %s\nusage: %s --corpus DIR [--regressions DIR]... [FILE]...\n", program,
               problem.c_str(), program);
  return 2;
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<fs::path> inputs;
  bool corpus = false;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--corpus" || arg == "--regressions") {
      if (i + 1 == argc) return usage(argv[0], arg + " needs a folder");
      const fs::path dir = argv[++i];
      if (!fs::is_directory(dir))
        return usage(argv[0], arg.substr(2) + " folder " + dir.string() + " is missing");
      const std::vector<fs::path> found = inputsIn(dir);
      if (arg == "--corpus") {
        if (found.empty()) return usage(argv[0], "corpus folder " + dir.string() + " holds no input");
        corpus = true;
      }
      inputs.insert(inputs.end(), found.begin(), found.end());
    } else if (fs::is_regular_file(arg)) {
      inputs.emplace_back(arg);
    } else {
      return usage(argv[0], "no input file " + arg);
    }
  }
  if (!corpus) return usage(argv[0], "no --corpus folder given");
  for (const fs::path& p : inputs) {
    std::ifstream in(p, std::ios::binary);
    std::vector<std::uint8_t> bytes((std::istreambuf_iterator<char>(in)), {});
    LLVMFuzzerTestOneInput(bytes.data(), bytes.size());
  }
  std::printf("replayed %zu inputs\n", inputs.size());
  return 0;
}
