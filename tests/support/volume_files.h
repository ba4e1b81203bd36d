// Test helpers for the volume readers: whole-file reads and writes, gzip and bzip2 compression, and
// expectations on cip::Error messages (and the scratch folder of support/scratch_dir.h).
#pragma once
#include <bzlib.h>
#include <gtest/gtest.h>
#include <zlib.h>

#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <string>
#include <vector>

#include "cip/core/error.h"
#include "scratch_dir.h"

namespace cip::test {

inline std::string sharedData(const std::string& name) {
  return std::string(CIP_SHARED_DATA) + "/" + name;
}

/// A file of the source tree, by its path from the project root.
inline std::string sourceFile(const std::string& relative) {
  return std::string(CIP_SOURCE_DIR) + "/" + relative;
}

inline std::string readAll(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

inline void writeAll(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

/// gzip-compresses `data` (gzip wrapper, as written by the gzip tool).
inline std::string gzipBytes(const std::string& data) {
  z_stream zs{};
  if (deflateInit2(&zs, 6, Z_DEFLATED, 15 + 16, 8, Z_DEFAULT_STRATEGY) != Z_OK)
    throw std::runtime_error("zlib");
  std::string out(deflateBound(&zs, static_cast<uLong>(data.size())) + 64, '\0');
  zs.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(data.data()));
  zs.avail_in = static_cast<uInt>(data.size());
  zs.next_out = reinterpret_cast<Bytef*>(out.data());
  zs.avail_out = static_cast<uInt>(out.size());
  int ret = deflate(&zs, Z_FINISH);
  deflateEnd(&zs);
  if (ret != Z_STREAM_END) throw std::runtime_error("zlib deflate");
  out.resize(zs.total_out);
  return out;
}

/// bzip2-compresses `data` (as written by the bzip2 tool).
inline std::string bzip2Bytes(const std::string& data) {
  std::string out(data.size() + data.size() / 100 + 1024, '\0');
  auto n = static_cast<unsigned>(out.size());
  if (BZ2_bzBuffToBuffCompress(out.data(), &n, const_cast<char*>(data.data()),
                               static_cast<unsigned>(data.size()), 9, 0, 0) != BZ_OK)
    throw std::runtime_error("bzip2");
  out.resize(n);
  return out;
}

/// Runs `f`, expects a cip::Error whose message contains every string in `parts`.
inline void expectError(const std::function<void()>& f, const std::vector<std::string>& parts) {
  try {
    f();
    ADD_FAILURE() << "expected cip::Error containing '" << (parts.empty() ? "" : parts[0]) << "'";
  } catch (const Error& e) {
    std::string what = e.what();
    for (const auto& p : parts)
      EXPECT_NE(what.find(p), std::string::npos) << "message: " << what << "\nmissing: " << p;
    EXPECT_EQ(what.find('\n'), std::string::npos) << "message should be one line: " << what;
  }
}

}  // namespace cip::test
