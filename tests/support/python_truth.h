// Truth from an independent reader or writer run in Python (nibabel, VTK): a script writes its test files
// into a folder and prints one manifest line per case (tests/support/nibabel_files.py describes the format);
// the tests read the same files with cip and compare placement and samples.
#pragma once
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iterator>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "cip/core/grid_geometry.h"

namespace cip::test {

/// The Python that has Debian's python3-nibabel and python3-vtk9.
inline const char* kSystemPython = "/usr/bin/python3";

struct TruthCase {
  std::string path;
  int frame = -1;    ///< frame of a 4-D file, -1 for a 3-D one
  std::string kind;  ///< "affine" (RAS), "pixdim" (no transform), "lps" (MetaImage)
  Eigen::Matrix4d affine;
  std::array<std::int64_t, 3> dims{};
  std::string truth;  ///< float64 samples, x fastest; "-" for none
};

/// Runs `script` with the system Python on `outDir` and parses its manifest. Returns nothing when the
/// script's module is missing (exit status 3) or Python itself is; fails the test on any other error.
inline std::optional<std::vector<TruthCase>> runTruthScript(const std::string& script,
                                                            const std::string& outDir) {
  if (access(kSystemPython, X_OK) != 0) return std::nullopt;
  const std::string command = std::string(kSystemPython) + " " + script + " " + outDir;
  std::FILE* pipe = popen(command.c_str(), "r");
  if (!pipe) {
    ADD_FAILURE() << "cannot run " << command;
    return std::nullopt;
  }
  std::string output;
  char buffer[4096];
  while (std::size_t n = std::fread(buffer, 1, sizeof buffer, pipe)) output.append(buffer, n);
  const int status = pclose(pipe);
  if (WIFEXITED(status) && WEXITSTATUS(status) == 3) return std::nullopt;
  if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) {
    ADD_FAILURE() << command << " failed with status " << status;
    return std::nullopt;
  }
  std::vector<TruthCase> cases;
  std::istringstream lines(output);
  for (std::string line; std::getline(lines, line);) {
    std::istringstream in(line);
    TruthCase c;
    in >> c.path >> c.frame >> c.kind;
    for (int n = 0; n < 16; ++n) in >> c.affine(n / 4, n % 4);
    in >> c.dims[0] >> c.dims[1] >> c.dims[2] >> c.truth;
    if (in.fail()) {
      ADD_FAILURE() << "bad manifest line: " << line;
      continue;
    }
    cases.push_back(c);
  }
  return cases;
}

/// The float64 samples of a truth file.
inline std::vector<double> readTruthSamples(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  std::vector<double> values(bytes.size() / sizeof(double));
  std::memcpy(values.data(), bytes.data(), values.size() * sizeof(double));
  return values;
}

/// Expects `geometry` to map every corner and the centre of the index box as the 4x4 `affine` does, to 1e-9.
inline void expectSamePlacement(const GridGeometry& geometry, const Eigen::Matrix4d& affine,
                                const std::string& what) {
  std::vector<Vec3> points;
  for (int corner = 0; corner < 8; ++corner) {
    Vec3 p;
    for (int a = 0; a < 3; ++a) p[a] = (corner >> a & 1) ? static_cast<double>(geometry.dims[a] - 1) : 0.0;
    points.push_back(p);
  }
  points.push_back(
      Vec3(0.5 * static_cast<double>(geometry.dims[0]), 1.25, 0.75 * static_cast<double>(geometry.dims[2])));
  for (const Vec3& ijk : points) {
    const Vec3 cip = geometry.origin + geometry.direction * geometry.spacing.cwiseProduct(ijk);
    const Vec3 truth = affine.topLeftCorner<3, 3>() * ijk + affine.topRightCorner<3, 1>();
    EXPECT_LT((cip - truth).cwiseAbs().maxCoeff(), 1e-9)
        << what << " index " << ijk.transpose() << ": cip " << cip.transpose() << ", truth "
        << truth.transpose();
  }
}

}  // namespace cip::test
