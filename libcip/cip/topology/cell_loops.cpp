#include "cip/topology/cell_loops.h"

#include <cmath>
#include <vector>

#include "cip/topology/cube_topology.h"

namespace cip {

namespace {

double dist(double ax, double ay, double bx, double by) {
  return std::hypot(ax - bx, ay - by);
}

struct Segment {
  int face, from, to;  // edges, oriented
};

}  // namespace

bool cutsOffDiagonal03(const std::array<double, 4>& t, bool vertex0Positive) {
  // Crossing points in face coordinates: edge 0 -> (t0,0), 1 -> (t1,1), 2 -> (0,t2), 3 -> (1,t3).
  double around03 = dist(t[0], 0, 0, t[2]) + dist(t[1], 1, 1, t[3]);
  double around12 = dist(t[0], 0, 1, t[3]) + dist(t[1], 1, 0, t[2]);
  if (around03 != around12) return around03 < around12;
  return !vertex0Positive;  // tie: cut off the negative diagonal
}

int CellLoops::sideFace(int c) const {
  return cube::commonFace(edges[c], edges[nextCorner(c)]);
}

int CellLoops::nextCorner(int c) const {
  int start = 0;
  for (int l = 0; l < numLoops; ++l) {
    int end = start + loopSize[l];
    if (c < end) return c + 1 < end ? c + 1 : start;
    start = end;
  }
  return -1;
}

namespace {

/// The loops traced from the faces' segments (buildCellLoops looks them up in a table of these).
CellLoops traceCellLoops(std::uint8_t config, std::uint8_t pairing03Mask) {
  using namespace cube;
  const std::uint16_t crossed = crossedEdges(config);
  Segment segs[12];
  int numSegs = 0;
  auto positive = [&](int v) { return ((config >> v) & 1) != 0; };
  // Orients a segment on face f between edges e1, e2 so that the positive side is on its left seen from
  // outside.
  auto addSegment = [&](int f, int e1, int e2) {
    int axis = faceAxis(f);
    double n[3] = {0, 0, 0};
    n[axis] = faceSide(f) ? 1.0 : -1.0;  // outward normal
    auto mid = [](int e) {
      auto a = vertexCoords(edgeVertex(e, 0)), b = vertexCoords(edgeVertex(e, 1));
      return std::array<double, 3>{(a[0] + b[0]) * 0.5, (a[1] + b[1]) * 0.5, (a[2] + b[2]) * 0.5};
    };
    auto m1 = mid(e1), m2 = mid(e2);
    int pv = positive(edgeVertex(e1, 0)) ? edgeVertex(e1, 0) : edgeVertex(e1, 1);
    auto pc = vertexCoords(pv);
    double d[3] = {m2[0] - m1[0], m2[1] - m1[1], m2[2] - m1[2]};
    double q[3] = {pc[0] - m1[0], pc[1] - m1[1], pc[2] - m1[2]};
    double cross[3] = {d[1] * q[2] - d[2] * q[1], d[2] * q[0] - d[0] * q[2], d[0] * q[1] - d[1] * q[0]};
    double side = cross[0] * n[0] + cross[1] * n[1] + cross[2] * n[2];
    segs[numSegs++] = side > 0 ? Segment{f, e1, e2} : Segment{f, e2, e1};
  };
  for (int f = 0; f < kFaces; ++f) {
    int ke[4], nk = 0;
    for (int k = 0; k < 4; ++k)
      if ((crossed >> faceEdge(f, k)) & 1) ke[nk++] = k;
    if (nk == 2) {
      addSegment(f, faceEdge(f, ke[0]), faceEdge(f, ke[1]));
    } else if (nk == 4) {
      if ((pairing03Mask >> f) & 1) {  // around vertex 0: edges 0,2; around vertex 3: edges 1,3
        addSegment(f, faceEdge(f, 0), faceEdge(f, 2));
        addSegment(f, faceEdge(f, 1), faceEdge(f, 3));
      } else {  // around vertex 1: edges 0,3; around vertex 2: edges 1,2
        addSegment(f, faceEdge(f, 0), faceEdge(f, 3));
        addSegment(f, faceEdge(f, 1), faceEdge(f, 2));
      }
    }
  }
  CellLoops loops;
  int segFrom[12];  // segment that starts at each edge
  for (int e = 0; e < 12; ++e) segFrom[e] = -1;
  for (int s = 0; s < numSegs; ++s) {
    segFrom[segs[s].from] = s;
    loops.faceMask = static_cast<std::uint8_t>(loops.faceMask | (1u << segs[s].face));
  }
  bool used[12] = {};
  int corner = 0;
  for (int e0 = 0; e0 < kEdges; ++e0) {
    if (!((crossed >> e0) & 1) || used[e0] || segFrom[e0] < 0) continue;
    int size = 0, e = e0;
    do {
      used[e] = true;
      loops.edges[corner++] = static_cast<std::int8_t>(e);
      ++size;
      e = segs[segFrom[e]].to;
    } while (e != e0 && !used[e] && segFrom[e] >= 0);
    loops.loopSize[loops.numLoops++] = static_cast<std::uint8_t>(size);
  }
  return loops;
}

/// Every cell's loops, traced once per process: per configuration one entry per pairing of its ambiguous
/// faces (the other faces' bits do not matter). The builder asks for them for every cell.
class LoopTable {
 public:
  LoopTable() {
    for (int c = 0; c < 256; ++c) {
      const auto config = static_cast<std::uint8_t>(c);
      std::uint8_t ambiguous = 0;
      for (int f = 0; f < 6; ++f)
        if (cube::isAmbiguousFace(config, f)) ambiguous = static_cast<std::uint8_t>(ambiguous | (1u << f));
      ambiguous_[c] = ambiguous;
      first_[c] = static_cast<std::uint32_t>(loops_.size());
      // Every subset of the ambiguous faces, in the order of their compressed bits (at()).
      const int n = __builtin_popcount(ambiguous);
      for (int k = 0; k < (1 << n); ++k) {
        std::uint8_t pairing = 0;
        int bit = 0;
        for (int f = 0; f < 6; ++f)
          if ((ambiguous >> f) & 1) {
            if ((k >> bit) & 1) pairing = static_cast<std::uint8_t>(pairing | (1u << f));
            ++bit;
          }
        loops_.push_back(traceCellLoops(config, pairing));
      }
    }
  }
  const CellLoops& at(std::uint8_t config, std::uint8_t pairing) const {
    const std::uint8_t ambiguous = ambiguous_[config];
    std::uint32_t k = 0;
    int bit = 0;
    for (unsigned rest = ambiguous; rest; rest &= rest - 1, ++bit)
      if (pairing & (rest & (~rest + 1))) k |= 1u << bit;
    return loops_[first_[config] + k];
  }

 private:
  std::array<std::uint8_t, 256> ambiguous_{};
  std::array<std::uint32_t, 256> first_{};
  std::vector<CellLoops> loops_;
};

}  // namespace

CellLoops buildCellLoops(std::uint8_t config, std::uint8_t pairing03Mask) {
  static const LoopTable table;
  return table.at(config, pairing03Mask);
}

}  // namespace cip
