/// @file lewiner_marching_cubes.h
/// @brief Marching cubes with the case tables of Lewiner, Lopes, Vieira and Tavares ("Efficient
/// implementation of Marching Cubes' cases with topological guarantees", J. Graphics Tools 8(2), 2003), made
/// to give exactly the mesh of scikit-image's skimage.measure.marching_cubes (method 'lewiner' or
/// 'lorensen').
///
/// Samples are read in place from a strided array and converted to float32, as scikit-image converts its
/// volume; the level is subtracted in double. Cells are visited in scikit-image's order (array axis 2
/// fastest, axis 0 slowest), so vertices, faces, normals and values come out in the same order as
/// scikit-image's. Edge vertices sit at the inverse-distance-weighted crossing
/// (w = 1 / (eps + |value - level|)), i.e. the linear crossing; the interior vertex of the tilings that need
/// one is the same weighted mean of the eight corners. Ambiguous faces are decided by the asymptotic decider
/// and the interior by Lewiner's internal test (method 'lewiner'); 'lorensen' uses the classic 256-case
/// table. The traversal order defines the vertex numbering: slabs of layers walked in parallel are
/// joined in that order, the vertices of their shared planes and the float sums of their normals resolved as
/// the serial walk has them.
#pragma once
#include <array>
#include <cstdint>
#include <functional>
#include <vector>

#include "cip/volume/strided_samples.h"

namespace cip {

struct LewinerOptions {
  double level = 0.0;    ///< isovalue, subtracted from each float32 sample in double
  int stepSize = 1;      ///< cells of stepSize^3 samples (scikit-image's step_size), >= 1
  bool classic = false;  ///< Lorensen's 256-case table instead of Lewiner's cases and tests
  bool descent = true;   ///< gradient_direction 'descent' (faces reversed) or 'ascent'
  /// Optional boolean mask of the volume's shape: a cell is processed only where the mask is true at its
  /// far corner (+stepSize on every axis), as scikit-image tests it. nullptr = every cell.
  const StridedSamples* mask = nullptr;
  /// Called with the fraction done after each layer of cells, if set, from any of the worker threads; may
  /// throw to stop the walk.
  std::function<void(double)> progress;
  /// Worker threads (TBB), 0 = all. Without a mask, slabs of cell layers are walked in parallel and joined so
  /// that the result is the serial walk's, bit for bit, for any number of threads.
  int threads = 0;
};

/// scikit-image's four outputs: vertices in array axis order (index units, float32), faces as vertex indices,
/// unit normals (index-space gradients pointing to lower values, accumulated over the cells around a vertex),
/// values (the largest range of the level-relative samples, including 0, among the cells around a vertex).
struct LewinerMesh {
  std::vector<std::array<float, 3>> vertices;
  std::vector<std::array<std::int32_t, 3>> faces;
  std::vector<std::array<float, 3>> normals;
  std::vector<float> values;
};

/// The mesh of `volume` (at least 2 samples per axis). Throws cip::Error for a bad view, step or mask shape,
/// or more vertices than int32 faces can index.
LewinerMesh lewinerMarchingCubes(const StridedSamples& volume, const LewinerOptions& options);

/// scikit-image's remove_degenerate_faces: drops every face with two bitwise-equal vertex positions, merges
/// such vertices into the lower index (in face order, as scikit-image does) and drops the merged ones from
/// vertices, normals and values. `mesh.vertices` are the positions to compare (already scaled by spacing).
void removeDegenerateFaces(LewinerMesh& mesh);

}  // namespace cip
