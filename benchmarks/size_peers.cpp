#include "size_peers.h"

#include <malloc.h>
#include <meshoptimizer.h>
#include <tbb/global_control.h>
#include <tbb/info.h>
#include <zstd.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <limits>
#include <nlohmann/json.hpp>
#include <stdexcept>
#include <vector>

#include "cip/mesh/ply.h"
#include "cip/model/model_file.h"

namespace cipbench {
namespace {

using Clock = std::chrono::steady_clock;

/// Best wall time of at least `reps` runs of `fn`, and of more while all runs together took less than
/// `minSeconds` (so that small inputs get enough runs for a stable best); before each (untimed) `release`
/// frees what the previous run kept and the heap's free memory goes back to the system, as in a fresh
/// process.
double bestOf(int reps, double minSeconds, const std::function<void()>& fn,
              const std::function<void()>& release = {}) {
  double best = std::numeric_limits<double>::infinity(), total = 0;
  for (int r = 0; r < std::max(1, reps) || (total < minSeconds && r < 10000); ++r) {
    if (release) release();
    malloc_trim(0);
    const auto t0 = Clock::now();
    fn();
    const double dt = std::chrono::duration<double>(Clock::now() - t0).count();
    best = std::min(best, dt);
    total += dt;
  }
  return best;
}

std::vector<std::uint8_t> readFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error("cannot read " + path);
  return std::vector<std::uint8_t>(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

void emit(const nlohmann::json& j, const std::string& path) {
  const std::string text = j.dump(2) + "\n";
  std::fputs(text.c_str(), stdout);
  if (path.empty()) return;
  std::ofstream out(path);
  if (!out) throw std::runtime_error("cannot write " + path);
  out << text;
}

// ---------------------------------------------------------------------------------------------------------------
// meshoptimizer

constexpr int kPositionBits = 16;
/// What a decoder needs besides the three encoded streams: the bounds (6 float32), vertex and index counts,
/// the normal bits and the three stream lengths (4 bytes each).
constexpr std::size_t kHeaderBytes = 6 * 4 + 2 * 4 + 4 + 3 * 4;

struct MeshoptEncoded {
  std::array<float, 3> lo{}, extent{};
  std::size_t vertexCount = 0, indexCount = 0;
  int normalBits = 0;            ///< 0: no normals
  std::size_t normalStride = 0;  ///< bytes per vertex of the normal stream (4: int8 x,y; 8: int16)
  std::vector<std::uint8_t> positions, normals, indices;  ///< the encoded streams
  std::vector<std::uint32_t> source;  ///< per encoded vertex, the input vertex (for the checks only)
  std::vector<std::uint32_t> order;   ///< the encoded index buffer before encoding (for the checks only)
  std::size_t bytes() const { return kHeaderBytes + positions.size() + normals.size() + indices.size(); }
};

struct MeshoptDecoded {
  std::vector<float> positions, normals;  ///< 3 per vertex
  std::vector<std::uint32_t> indices;
};

/// meshoptimizer's recommended pipeline: quantise (positions to 16 bits per component over the mesh's bounds,
/// unit normals octahedral with `normalBits` bits per component, meshopt_encodeFilterOct), vertex cache order
/// (meshopt_optimizeVertexCache), vertex fetch order over both streams (meshopt_optimizeVertexFetchRemap,
/// which is meshopt_optimizeVertexFetch for more than one stream), then meshopt_encodeVertexBuffer on each
/// stream and meshopt_encodeIndexBuffer.
MeshoptEncoded meshoptEncode(const cip::TriangleMesh& mesh, int normalBits) {
  MeshoptEncoded e;
  const std::size_t n = mesh.vertexCount();
  e.vertexCount = n;
  e.indexCount = mesh.triangleCount() * 3;
  std::array<float, 3> hi{};
  for (int c = 0; c < 3; ++c) {
    e.lo[c] = std::numeric_limits<float>::infinity();
    hi[c] = -std::numeric_limits<float>::infinity();
  }
  for (const auto& p : mesh.positions)
    for (int c = 0; c < 3; ++c) {
      e.lo[c] = std::min(e.lo[c], static_cast<float>(p[c]));
      hi[c] = std::max(hi[c], static_cast<float>(p[c]));
    }
  for (int c = 0; c < 3; ++c) e.extent[c] = n > 0 ? hi[c] - e.lo[c] : 0.0f;
  std::vector<std::uint16_t> pos(4 * n, 0);
  for (std::size_t v = 0; v < n; ++v)
    for (int c = 0; c < 3; ++c) {
      const float t =
          e.extent[c] > 0 ? (static_cast<float>(mesh.positions[v][c]) - e.lo[c]) / e.extent[c] : 0.0f;
      pos[4 * v + c] = static_cast<std::uint16_t>(meshopt_quantizeUnorm(t, kPositionBits));
    }
  std::vector<std::uint8_t> nrm;
  if (mesh.hasNormals()) {
    e.normalBits = normalBits;
    e.normalStride = normalBits <= 8 ? 4 : 8;
    std::vector<float> n4(4 * n, 0.0f);
    for (std::size_t v = 0; v < n; ++v)
      for (int c = 0; c < 3; ++c) n4[4 * v + c] = static_cast<float>(mesh.normals[v][c]);
    nrm.resize(e.normalStride * n);
    meshopt_encodeFilterOct(nrm.data(), n, e.normalStride, normalBits, n4.data());
  }
  std::vector<std::uint32_t> input(e.indexCount);
  for (std::size_t t = 0; t < mesh.triangleCount(); ++t)
    for (int k = 0; k < 3; ++k) input[3 * t + k] = mesh.triangles[t][k];
  e.order.resize(e.indexCount);
  meshopt_optimizeVertexCache(e.order.data(), input.data(), e.indexCount, n);
  std::vector<std::uint32_t> remap(n);
  const std::size_t used = meshopt_optimizeVertexFetchRemap(remap.data(), e.order.data(), e.indexCount, n);
  meshopt_remapIndexBuffer(e.order.data(), e.order.data(), e.indexCount, remap.data());
  std::vector<std::uint16_t> posOut(4 * used);
  meshopt_remapVertexBuffer(posOut.data(), pos.data(), n, 4 * sizeof(std::uint16_t), remap.data());
  e.source.assign(used, 0);
  for (std::size_t v = 0; v < n; ++v)
    if (remap[v] != ~0u) e.source[remap[v]] = static_cast<std::uint32_t>(v);
  e.vertexCount = used;
  e.positions.resize(meshopt_encodeVertexBufferBound(used, 4 * sizeof(std::uint16_t)));
  e.positions.resize(meshopt_encodeVertexBuffer(e.positions.data(), e.positions.size(), posOut.data(), used,
                                                4 * sizeof(std::uint16_t)));
  if (!nrm.empty()) {
    std::vector<std::uint8_t> nrmOut(e.normalStride * used);
    meshopt_remapVertexBuffer(nrmOut.data(), nrm.data(), n, e.normalStride, remap.data());
    e.normals.resize(meshopt_encodeVertexBufferBound(used, e.normalStride));
    e.normals.resize(
        meshopt_encodeVertexBuffer(e.normals.data(), e.normals.size(), nrmOut.data(), used, e.normalStride));
  }
  e.indices.resize(meshopt_encodeIndexBufferBound(e.indexCount, used));
  e.indices.resize(
      meshopt_encodeIndexBuffer(e.indices.data(), e.indices.size(), e.order.data(), e.indexCount));
  return e;
}

struct Bytes {
  const std::uint8_t* data;
  std::size_t size;
};

/// Decodes the streams back to float positions, float unit normals and 32-bit indices (what a renderer or the
/// PLY reader hands on). `e` gives the header (bounds, counts, normal bits); the streams are `p`, `nr`, `ix`.
MeshoptDecoded meshoptDecode(const MeshoptEncoded& e, Bytes p, Bytes nr, Bytes ix) {
  MeshoptDecoded d;
  const std::size_t n = e.vertexCount;
  std::vector<std::uint16_t> pos(4 * n);
  if (meshopt_decodeVertexBuffer(pos.data(), n, 4 * sizeof(std::uint16_t), p.data, p.size) != 0)
    throw std::runtime_error("meshopt: position stream does not decode");
  d.indices.resize(e.indexCount);
  if (meshopt_decodeIndexBuffer(d.indices.data(), e.indexCount, sizeof(std::uint32_t), ix.data, ix.size) != 0)
    throw std::runtime_error("meshopt: index stream does not decode");
  d.positions.resize(3 * n);
  std::array<float, 3> step{};
  for (int c = 0; c < 3; ++c) step[c] = e.extent[c] / float((1 << kPositionBits) - 1);
  for (std::size_t v = 0; v < n; ++v)
    for (int c = 0; c < 3; ++c) d.positions[3 * v + c] = e.lo[c] + float(pos[4 * v + c]) * step[c];
  if (e.normalBits > 0) {
    std::vector<std::uint8_t> nrm(e.normalStride * n);
    if (meshopt_decodeVertexBuffer(nrm.data(), n, e.normalStride, nr.data, nr.size) != 0)
      throw std::runtime_error("meshopt: normal stream does not decode");
    meshopt_decodeFilterOct(nrm.data(), n, e.normalStride);
    d.normals.resize(3 * n);
    if (e.normalStride == 4) {
      const auto* q = reinterpret_cast<const std::int8_t*>(nrm.data());
      for (std::size_t i = 0; i < n; ++i)
        for (int c = 0; c < 3; ++c) d.normals[3 * i + c] = float(q[4 * i + c]) / 127.0f;
    } else {
      std::vector<std::int16_t> q(4 * n);
      std::copy_n(nrm.data(), nrm.size(), reinterpret_cast<std::uint8_t*>(q.data()));
      for (std::size_t i = 0; i < n; ++i)
        for (int c = 0; c < 3; ++c) d.normals[3 * i + c] = float(q[4 * i + c]) / 32767.0f;
    }
  }
  return d;
}
MeshoptDecoded meshoptDecode(const MeshoptEncoded& e) {
  return meshoptDecode(e, {e.positions.data(), e.positions.size()}, {e.normals.data(), e.normals.size()},
                       {e.indices.data(), e.indices.size()});
}

/// The decoded mesh against the input: same triangles (in the encoder's order), positions within the
/// quantisation step, normals' largest angle error. Throws when the triangles or positions differ.
nlohmann::json checkDecoded(const cip::TriangleMesh& mesh, const MeshoptEncoded& e, const MeshoptDecoded& d) {
  // The index codec keeps the triangles' order and orientation but may rotate a triangle's corners.
  bool same = d.indices.size() == e.order.size();
  for (std::size_t t = 0; same && t < e.order.size(); t += 3) {
    const std::uint32_t* a = &e.order[t];
    const std::uint32_t* b = &d.indices[t];
    same = false;
    for (int r = 0; r < 3 && !same; ++r)
      same = a[0] == b[r] && a[1] == b[(r + 1) % 3] && a[2] == b[(r + 2) % 3];
  }
  if (!same) throw std::runtime_error("meshopt: decoded triangles differ from the encoded ones");
  double posErr = 0, angle = 0;
  for (std::size_t v = 0; v < e.vertexCount; ++v) {
    const auto& p = mesh.positions[e.source[v]];
    for (int c = 0; c < 3; ++c) {
      const double step = e.extent[c] / double((1 << kPositionBits) - 1);
      if (step > 0) posErr = std::max(posErr, std::abs(d.positions[3 * v + c] - p[c]) / step);
    }
    if (!d.normals.empty()) {
      const auto& nn = mesh.normals[e.source[v]];
      double dot = 0, len = 0;
      for (int c = 0; c < 3; ++c) {
        dot += d.normals[3 * v + c] * nn[c];
        len += double(d.normals[3 * v + c]) * d.normals[3 * v + c];
      }
      if (len > 0 && nn.norm() > 0.5)
        angle = std::max(angle, std::acos(std::clamp(dot / std::sqrt(len) / nn.norm(), -1.0, 1.0)));
    }
  }
  if (posErr > 0.51) throw std::runtime_error("meshopt: a decoded position is off by more than half a step");
  return {{"max_position_error_steps", posErr}, {"max_normal_error_deg", angle * 57.29577951308232}};
}

std::vector<std::uint8_t> concatenate(const MeshoptEncoded& e) {
  std::vector<std::uint8_t> all(kHeaderBytes, 0);  // the header's contents do not matter to the sizes
  for (const auto* s : {&e.positions, &e.normals, &e.indices}) all.insert(all.end(), s->begin(), s->end());
  return all;
}

}  // namespace

void meshCodecs(const MeshCodecOptions& o) {
  const std::vector<std::uint8_t> file = readFile(o.ply);
  const cip::TriangleMesh mesh = cip::parsePly(file.data(), file.size(), o.ply);
  nlohmann::json j;
  j["ply"] = o.ply;
  j["ply_bytes"] = file.size();
  j["vertices"] = mesh.vertexCount();
  j["triangles"] = mesh.triangleCount();
  j["normals"] = mesh.hasNormals();
  j["meshoptimizer_version"] = MESHOPTIMIZER_VERSION;
  for (int normalBits : {8, 10}) {
    MeshoptEncoded e;
    // The 10-bit variant is there for its size: one run each.
    const int reps = normalBits == 8 ? o.reps : 1;
    const double minSeconds = normalBits == 8 ? o.minSeconds : 0.0;
    const double tEncode = bestOf(reps, minSeconds, [&] { e = meshoptEncode(mesh, normalBits); });
    MeshoptDecoded d;
    const double tDecode = bestOf(reps, minSeconds, [&] { d = meshoptDecode(e); });
    const std::string key = normalBits == 8 ? "meshopt" : "meshopt_oct10";
    j[key] = {{"bytes", e.bytes()},
              {"position_bits", kPositionBits},
              {"normal_bits", e.normalBits},
              {"header_bytes", kHeaderBytes},
              {"position_stream_bytes", e.positions.size()},
              {"normal_stream_bytes", e.normals.size()},
              {"index_stream_bytes", e.indices.size()},
              {"encode_seconds", tEncode},
              {"decode_seconds", tDecode},
              {"check", checkDecoded(mesh, e, d)}};
    if (normalBits != 8) continue;
    // zstd on top of the meshoptimizer streams (their byte-wise deltas leave room for an entropy coder).
    std::vector<std::uint8_t> packed;
    const double tZstd = bestOf(o.reps, o.minSeconds, [&] {
      const std::vector<std::uint8_t> all = concatenate(meshoptEncode(mesh, normalBits));
      packed.resize(ZSTD_compressBound(all.size()));
      const std::size_t r = ZSTD_compress(packed.data(), packed.size(), all.data(), all.size(), o.zstdLevel);
      if (ZSTD_isError(r)) throw std::runtime_error(std::string("zstd: ") + ZSTD_getErrorName(r));
      packed.resize(r);
    });
    const std::vector<std::uint8_t> all = concatenate(e);
    std::vector<std::uint8_t> back;
    const double tUnzstd = bestOf(o.reps, o.minSeconds, [&] {
      back.resize(ZSTD_getFrameContentSize(packed.data(), packed.size()));
      const std::size_t r = ZSTD_decompress(back.data(), back.size(), packed.data(), packed.size());
      if (ZSTD_isError(r) || r != all.size()) throw std::runtime_error("zstd: round trip failed");
      // The stream lengths are in the header; `e` stands for it here.
      const std::uint8_t* at = back.data() + kHeaderBytes;
      const Bytes p{at, e.positions.size()}, nr{at + p.size, e.normals.size()},
          ix{at + p.size + nr.size, e.indices.size()};
      d = meshoptDecode(e, p, nr, ix);
    });
    if (back != all) throw std::runtime_error("zstd: round trip differs");
    checkDecoded(mesh, e, d);
    j["meshopt_zstd"] = {{"bytes", packed.size()},
                         {"zstd_level", o.zstdLevel},
                         {"encode_seconds", tZstd},
                         {"decode_seconds", tUnzstd}};
  }
  emit(j, o.json);
}

void modelIo(const ModelIoOptions& o) {
  const std::vector<std::uint8_t> modelData = readFile(o.model);
  const std::vector<std::uint8_t> plyData = readFile(o.ply);
  const cip::Model model = cip::parseModel(modelData.data(), modelData.size(), o.model);
  const cip::TriangleMesh mesh = cip::parsePly(plyData.data(), plyData.size(), o.ply);
  const std::string modelTmp = o.model + ".io-bench.cip", plyTmp = o.ply + ".io-bench.ply";
  nlohmann::json j;
  j["model"] = o.model;
  j["model_bytes"] = modelData.size();
  j["model_file_version"] = cip::kModelFileVersion;
  j["ply"] = o.ply;
  j["ply_bytes"] = plyData.size();
  j["reps"] = o.reps;
  j["model_reserialized_identical"] = cip::serializeModel(model) == modelData;
  j["rows"] = nlohmann::json::array();
  {
    // One untimed run of each operation first, so that no timed run pays for the process's warm-up (the first
    // read of each file, lazy binding, the first growth of the heap).
    cip::Model m = cip::readModel(o.model);
    cip::writeModel(m, modelTmp);
    cip::TriangleMesh t = cip::readPly(o.ply);
    cip::writePly(t, plyTmp);
  }
  const int all = tbb::info::default_concurrency();
  for (int threads : {1, all}) {
    if (threads == all && all == 1 && !j["rows"].empty()) break;
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism,
                              static_cast<std::size_t>(threads));
    cip::Model m;
    cip::TriangleMesh t;
    std::vector<std::uint8_t> bytes;
    const auto dropModel = [&] { m = cip::Model(); };
    const auto dropMesh = [&] { t = cip::TriangleMesh(); };
    const auto dropBytes = [&] { bytes = std::vector<std::uint8_t>(); };
    nlohmann::json s;
    const auto best = [&](const std::function<void()>& fn, const std::function<void()>& release) {
      return bestOf(o.reps, o.minSeconds, fn, release);
    };
    s["model_read"] = best([&] { m = cip::readModel(o.model); }, dropModel);
    s["model_parse"] =
        best([&] { m = cip::parseModel(modelData.data(), modelData.size(), o.model); }, dropModel);
    s["model_serialize"] = best([&] { bytes = cip::serializeModel(model); }, dropBytes);
    s["model_write"] = best([&] { cip::writeModel(model, modelTmp); }, {});
    s["ply_read"] = best([&] { t = cip::readPly(o.ply); }, dropMesh);
    s["ply_parse"] = best([&] { t = cip::parsePly(plyData.data(), plyData.size(), o.ply); }, dropMesh);
    s["ply_write"] = best([&] { cip::writePly(mesh, plyTmp); }, {});
    nlohmann::json mbs;
    for (const auto& [k, v] : s.items()) mbs[k] = double(plyData.size()) / v.get<double>() * 1e-6;
    j["rows"].push_back({{"threads", threads}, {"seconds", s}, {"ply_mb_per_s", mbs}});
  }
  std::filesystem::remove(modelTmp);
  std::filesystem::remove(plyTmp);
  emit(j, o.json);
}

}  // namespace cipbench
