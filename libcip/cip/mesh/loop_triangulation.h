/// @file loop_triangulation.h
/// @brief Triangulation of one cell loop (cell_loops.h) for marching-cubes style meshes.
///
/// A loop's corners lie on crossed cell edges; consecutive corners are joined by a side lying in a cell face,
/// and the neighbouring cell has the same side (reversed). A chord between two corners whose edges share a
/// face lies in that face; if both cells sharing the face used chords there they could coincide or cross.
/// So, in order of preference:
///  1. Interior: sides plus chords between corners on edges without a common face only. Such chords pass
///     through the cell's interior and belong to no other cell. Taken whenever one exists (always for
///     loops of up to 7 corners).
///  2. Upper-face chords: chords lying in the cell's faces with side 1 (x, y or z = 1) are allowed too,
///     at a large cost per chord. Every grid face is the side-1 face of exactly one of its two cells, so
///     such a chord still belongs to one cell only. It joins crossings of the two different segment pairs
///     of an ambiguous face and runs through the band between them, where the neighbour has no triangles.
///  3. Centre fan: a new vertex (the corners' mean; inside the cell, which is convex) joined to every
///     side.
/// Within a tier the triangulation with the smallest summed chord length is taken (ties: the first in a fixed
/// order), so the result depends on the loop alone. All triangles stay in the cell.
///
/// Orientation: triangles keep the loop's order, so with cell_loops' convention (positive side on the left of
/// each side, seen from outside the cell) every triangle's right-handed normal points towards the positive
/// side (values above the isovalue).
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
