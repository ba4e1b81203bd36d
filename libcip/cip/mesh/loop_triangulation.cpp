#include "cip/mesh/loop_triangulation.h"

#include <limits>

#include "cip/topology/cube_topology.h"

namespace cip {

namespace {

constexpr int kMax = 12;
constexpr double kInfinity = std::numeric_limits<double>::infinity();
/// Cost of one upper-face chord: more than any set of interior chords of a unit cell can sum to.
constexpr double kFaceChordCost = 1e3;

/// Minimum-weight polygon triangulation (dynamic programming over sub-polygons i..j). Returns false when
/// every triangulation needs a forbidden chord.
bool minimumTriangulation(int n, const std::int8_t* edges, const Vec3* p, bool upperFaceChords,
                          LoopTriangles& out) {
  double chord[kMax][kMax];
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j < n; ++j) {
      int f;
      if (i == j || j == i + 1 || i == j + 1 || (i == 0 && j == n - 1) || (j == 0 && i == n - 1)) {
        chord[i][j] = 0;  // a side of the loop (or the same corner)
      } else if ((f = cube::commonFace(edges[i], edges[j])) < 0) {
        chord[i][j] = (p[i] - p[j]).norm();
      } else if (upperFaceChords && cube::faceSide(f) == 1) {
        chord[i][j] = kFaceChordCost + (p[i] - p[j]).norm();
      } else {
        chord[i][j] = kInfinity;
      }
    }
  }
  double cost[kMax][kMax];
  int split[kMax][kMax];
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j < n; ++j) {
      cost[i][j] = 0;
      split[i][j] = -1;
    }
  }
  for (int len = 2; len < n; ++len) {
    for (int i = 0; i + len < n; ++i) {
      int j = i + len;
      double best = kInfinity;
      int bestK = -1;
      for (int k = i + 1; k < j; ++k) {
        double c = cost[i][k] + cost[k][j] + chord[i][k] + chord[k][j];
        if (c < best) {
          best = c;
          bestK = k;
        }
      }
      cost[i][j] = best;
      split[i][j] = bestK;
    }
  }
  if (!(cost[0][n - 1] < kInfinity)) return false;
  out.count = 0;
  int stack[2 * kMax][2], top = 0;
  stack[top][0] = 0;
  stack[top][1] = n - 1;
  ++top;
  while (top > 0) {
    --top;
    int i = stack[top][0], j = stack[top][1];
    if (j - i < 2) continue;
    int k = split[i][j];
    out.triangles[out.count++] = {static_cast<std::uint8_t>(i), static_cast<std::uint8_t>(k),
                                  static_cast<std::uint8_t>(j)};
    stack[top][0] = i;
    stack[top][1] = k;
    ++top;
    stack[top][0] = k;
    stack[top][1] = j;
    ++top;
  }
  return true;
}

}  // namespace

LoopTriangles triangulateLoop(int size, const std::int8_t* edges, const Vec3* points) {
  LoopTriangles out;
  if (size < 3 || size > kMax) return out;
  out.kind = LoopTriangulation::Interior;
  if (minimumTriangulation(size, edges, points, false, out)) return out;
  out.kind = LoopTriangulation::UpperFaceChords;
  if (minimumTriangulation(size, edges, points, true, out)) return out;
  out.kind = LoopTriangulation::CentreFan;
  out.count = size;
  for (int i = 0; i < size; ++i) {
    out.triangles[i] = {static_cast<std::uint8_t>(i), static_cast<std::uint8_t>((i + 1) % size),
                        static_cast<std::uint8_t>(size)};
  }
  return out;
}

}  // namespace cip
