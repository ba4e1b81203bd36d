/// @file cell_loops.h
/// @brief Boundary loops of a cell's isosurface piece, from its marching-cubes sign configuration.
///
/// Each crossed edge carries one isovertex (a corner of the patch). On each face the crossings are joined by
/// segments (the patch's sides); an ambiguous face (four crossings) is paired by minimal summed length,
/// decided from that face's data alone (so both cells sharing the face agree). Segments chain into 1..4
/// closed loops with 3..12 corners in all. Loops are oriented so that, seen from outside the cell, the
/// positive side of every segment lies to its left.
#pragma once
#include <array>
#include <cstdint>

namespace cip {

/// Pairing of an ambiguous face's crossings, from the crossings' positions along the face's canonical edges
/// (cube_topology.h): t[k] in [0,1] measured from edge k's start. Returns true when the pairing that cuts off
/// face vertices 0 and 3 (canonical (u,v) = (0,0) and (1,1)) has the smaller summed segment length. On an
/// exact tie the negative vertices are cut off (the positive region stays connected across the face).
/// `vertex0Positive` is the sign of canonical face vertex 0.
bool cutsOffDiagonal03(const std::array<double, 4>& t, bool vertex0Positive);

/// The loops of one cell.
struct CellLoops {
  int numLoops = 0;
  std::array<std::uint8_t, 4> loopSize{};  ///< corners in each loop (>= 3)
  std::array<std::int8_t, 12> edges{};  ///< the crossed edge of each corner, loop after loop, in loop order
  std::uint8_t faceMask = 0;            ///< faces that carry at least one side (the patch's bounding planes)
  int numCorners() const { return loopSize[0] + loopSize[1] + loopSize[2] + loopSize[3]; }
  /// Face of the side that leaves corner `c` (global corner number) towards the next corner of its loop.
  int sideFace(int c) const;
  /// Index of the corner after `c` within its loop.
  int nextCorner(int c) const;
};

/// Builds the loops for sign configuration `config` (bit v set = vertex v positive). `pairing03Mask` has bit
/// f set when ambiguous face f pairs its crossings around face vertices 0 and 3 (see cutsOffDiagonal03); bits
/// of faces that are not ambiguous are ignored.
CellLoops buildCellLoops(std::uint8_t config, std::uint8_t pairing03Mask);

}  // namespace cip
