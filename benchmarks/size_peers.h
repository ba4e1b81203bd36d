// The size and input/output peers of the model file (benchmarks/run.py's size section):
//   cip_bench mesh-codecs --ply MC.ply [--json OUT] [--reps N] [--min-seconds S]
//       the marching-cubes mesh encoded with meshoptimizer (16-bit positions over the mesh bounds, octahedral
//       normals, vertex cache and fetch order, vertex and index codecs), alone and with zstd on top: byte
//       counts and the best encode and decode times of N runs.
//   cip_bench model-io --model M.cip --ply MC.ply [--json OUT] [--reps N] [--min-seconds S]
//       reading, parsing, serialising and writing the model against reading and writing the PLY of the same
//       cells, on one thread and on all, as seconds and as MB/s of the PLY's bytes.
#pragma once
#include <string>

namespace cipbench {

struct MeshCodecOptions {
  std::string ply;        ///< the marching-cubes mesh (binary PLY, as `extract --mc-mesh` writes it)
  std::string json;       ///< output JSON (empty: stdout only)
  int reps = 3;           ///< timed runs of each encode and decode; the best counts
  double minSeconds = 0;  ///< more runs while the runs of one operation took less than this altogether
  int zstdLevel = 19;
};

/// Encodes the PLY's mesh with meshoptimizer (and meshoptimizer + zstd), checks the decoded mesh against the
/// input, and prints (and writes to options.json) the byte counts and times as JSON.
void meshCodecs(const MeshCodecOptions& options);

struct ModelIoOptions {
  std::string model;      ///< a .cip file
  std::string ply;        ///< the marching-cubes mesh of the same model (the size the MB/s figures divide)
  std::string json;       ///< output JSON (empty: stdout only)
  int reps = 5;           ///< timed runs of each operation; the best counts
  double minSeconds = 0;  ///< more runs while the runs of one operation took less than this altogether
};

/// Times readModel, parseModel (in memory), serializeModel and writeModel on the model and readPly, parsePly
/// and writePly on the mesh, with TBB limited to one thread and with all threads; prints (and writes to
/// options.json) seconds and MB/s of the PLY's bytes.
void modelIo(const ModelIoOptions& options);

}  // namespace cipbench
