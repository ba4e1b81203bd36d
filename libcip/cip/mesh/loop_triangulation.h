/// @file loop_triangulation.h
/// @brief Triangulation of one cell loop (cell_loops.h) for marching-cubes style meshes.
///
/// Chords through the cell's interior are preferred, then chords in the cell's upper faces (which belong to
/// this cell only), then a centre fan; within a tier the shortest total chord length wins, so the result
/// depends on the loop alone and neighbouring cells never share or cross chords. Triangles keep the loop's
/// orientation: normals point towards the positive side. docs/meshes.md gives the reasoning.
#pragma once
#include <array>
#include <cstdint>

#include "cip/core/vec3.h"

namespace cip {

enum class LoopTriangulation : std::uint8_t { Interior = 0, UpperFaceChords = 1, CentreFan = 2 };

/// Triangles of one loop; corners are numbered within the loop, and corner number `size` is the centre vertex
/// when kind == CentreFan.
struct LoopTriangles {
  LoopTriangulation kind = LoopTriangulation::Interior;
  int count = 0;
  std::array<std::array<std::uint8_t, 3>, 12> triangles{};
};

/// Triangulates a loop of `size` (3..12) corners lying on cell edges `edges[0..size)` (cube_topology.h
/// numbering) at positions `points` (any common frame, e.g. cell-local). Throws nothing; sizes outside 3..12
/// give count 0.
LoopTriangles triangulateLoop(int size, const std::int8_t* edges, const Vec3* points);

}  // namespace cip
