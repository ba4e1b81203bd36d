/// @file model_file_v2.h
/// @brief Version 2 of the `.cip` file (docs/model-format.md): a sign map of the crossed region per brick,
/// one quantised crossing parameter and one predicted, quantised normal per crossed edge, one side
/// coefficient per crossed face, all entropy-coded with zstd in chunks that are checked and decoded one
/// brick at a time. Lossy within stated bounds: the surface a v2 file stores is the surface every tool
/// downstream uses (extract decodes what it writes before it measures anything).
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "cip/model/model.h"

namespace cip {

/// Quantisation and chunking of a version 2 file. The defaults keep the stored surface within 0.01 voxel of
/// the full-precision one (docs/model-format.md says how that is measured).
struct ModelFileV2Options {
  int brick = 64;              ///< cells per brick edge (8..128): the unit of chunking
  int positionBits = 9;        ///< crossing parameter along its edge: t = q / (2^bits - 1), 4..16
  int normalBits = 9;          ///< octahedral step of the normal residual: 2^-bits, 6..16
  double sideStep = 0.002;     ///< side coefficients: absolute step near zero ...
  int sideMantissa = 6;        ///< ... and this many bits of relative precision above 2^bits steps
  double centralStep = 0.008;  ///< central coefficients, likewise
  int centralMantissa = 4;
  int zstdLevel = 3;  ///< the streams' zstd level, 1..19 (files written before: 9; a reader takes any)
  /// Cells whose stored surface the plain codes would move too far (estimated: surface_shift.h) get finer
  /// codes: their corners (refined vertices) and, in fitted models, first their coefficients
  /// (docs/model-format.md, "Refined vertices" and "Refined coefficients"). Off only to measure what that
  /// buys.
  bool refineMovingCells = true;

  /// The defaults for a model built with `method`: the paper's coefficients are recomputed from the stored
  /// corners and are more sensitive to them, so its normals get one more bit (and the vertices of cells that
  /// amplify rounding 8 more: docs/model-format.md, "Refined vertices").
  static ModelFileV2Options forMethod(PatchMethod method);
};

std::vector<std::uint8_t> serializeModelV2(const Model& model, const ModelFileV2Options& options = {});
/// Bytes of one kind of data summed over the chunks of a version 2 file, as stored (after compression), in
/// file order: sign rows, cell exceptions, face pairings, positions (low bytes), positions (high bytes),
/// normals, side coefficients, central coefficients, corner coefficients, zero normal components,
/// full-precision vertices, refined vertices (0 in files without them); then "header" (header and directory)
/// and "framing" (stream sizes). For reports of where a file's bytes go.
std::vector<std::pair<std::string, std::size_t>> modelFileV2Streams(const std::vector<std::uint8_t>& file);

/// modelTableCounts (model_file.h) of a version 2 file whose magic and version the caller has checked.
ModelTableCounts modelTableCountsV2(const std::uint8_t* data, std::size_t size, const std::string& name);

/// Parses a version 2 file whose magic and version the caller has checked (`data` is the whole file).
Model parseModelV2(const std::uint8_t* data, std::size_t size, const std::string& name);

}  // namespace cip
