/// @file cube_topology.h
/// @brief Fixed numbering of a grid cell's 8 vertices, 12 edges and 6 faces (cell-local coordinates, unit
/// cube).
///
///  - vertex v = x + 2y + 4z, at (x,y,z) in {0,1}^3.
///  - edge e = 4*axis + (a + 2b), where (a,b) are the edge's coordinates along the two other axes in
///  increasing axis
///    order; the edge runs from its vertex with coordinate 0 along `axis` to the one with coordinate 1.
///  - face f = 2*axis + side: the plane x[axis] = side. Its bounding-plane function B_f is x[axis] for side 0
///  and
///    1 - x[axis] for side 1, so B_f >= 0 inside the cell and B_f = 1 on the opposite face.
///  - a face's own 2-D frame: u = the lower of its two in-plane axes, v = the higher one. Its four edges in
///  canonical
///    order are: u-edge at v=0, u-edge at v=1, v-edge at u=0, v-edge at u=1 (see faceEdge()).
#pragma once
#include <array>
#include <cstdint>

namespace cip::cube {

constexpr int kVertices = 8, kEdges = 12, kFaces = 6;

constexpr std::array<int, 3> vertexCoords(int v) {
  return {v & 1, (v >> 1) & 1, (v >> 2) & 1};
}
constexpr int vertexIndex(int x, int y, int z) {
  return x + 2 * y + 4 * z;
}

constexpr int edgeAxis(int e) {
  return e / 4;
}
/// The two axes other than `axis`, in increasing order.
constexpr std::array<int, 2> otherAxes(int axis) {
  return axis == 0   ? std::array<int, 2>{1, 2}
         : axis == 1 ? std::array<int, 2>{0, 2}
                     : std::array<int, 2>{0, 1};
}
/// Vertex at the start (end = 0) or end (end = 1) of edge e.
constexpr int edgeVertex(int e, int end) {
  int axis = edgeAxis(e), a = e & 1, b = (e >> 1) & 1;
  auto o = otherAxes(axis);
  std::array<int, 3> c{0, 0, 0};
  c[axis] = end;
  c[o[0]] = a;
  c[o[1]] = b;
  return vertexIndex(c[0], c[1], c[2]);
}
/// The edge along `axis` whose coordinates along the other two axes are (a, b).
constexpr int edgeIndex(int axis, int a, int b) {
  return 4 * axis + a + 2 * b;
}
/// The two faces that contain edge e (the face across the first other axis first).
constexpr std::array<int, 2> edgeFaces(int e) {
  int axis = edgeAxis(e);
  auto o = otherAxes(axis);
  return {2 * o[0] + (e & 1), 2 * o[1] + ((e >> 1) & 1)};
}

constexpr int faceAxis(int f) {
  return f / 2;
}
constexpr int faceSide(int f) {
  return f & 1;
}
constexpr int oppositeFace(int f) {
  return f ^ 1;
}
/// Canonical edge k (0..3) of face f: 0 = u-edge at v=0, 1 = u-edge at v=1, 2 = v-edge at u=0, 3 = v-edge at
/// u=1.
constexpr int faceEdge(int f, int k) {
  int axis = faceAxis(f), side = faceSide(f);
  auto uv = otherAxes(axis);
  int edgeAlong = k < 2 ? uv[0] : uv[1];  // the edge runs along u for k=0,1 and along v for k=2,3
  int fixedOther = k < 2 ? uv[1] : uv[0];
  int fixedValue = k & 1;
  std::array<int, 3> c{0, 0, 0};
  c[axis] = side;
  c[fixedOther] = fixedValue;
  auto o = otherAxes(edgeAlong);
  return edgeIndex(edgeAlong, c[o[0]], c[o[1]]);
}
/// Canonical vertex k of face f: k = a + 2b at (u,v) = (a,b).
constexpr int faceVertex(int f, int k) {
  int axis = faceAxis(f);
  auto uv = otherAxes(axis);
  std::array<int, 3> c{0, 0, 0};
  c[axis] = faceSide(f);
  c[uv[0]] = k & 1;
  c[uv[1]] = (k >> 1) & 1;
  return vertexIndex(c[0], c[1], c[2]);
}
/// The face that contains both edges e1 != e2, or -1.
int commonFace(int e1, int e2);

namespace detail {
constexpr std::uint16_t computeCrossedEdges(int config) {
  std::uint16_t mask = 0;
  for (int e = 0; e < kEdges; ++e)
    if (((config >> edgeVertex(e, 0)) & 1) != ((config >> edgeVertex(e, 1)) & 1))
      mask = static_cast<std::uint16_t>(mask | (1u << e));
  return mask;
}
constexpr std::array<std::uint16_t, 256> crossedEdgesTable() {
  std::array<std::uint16_t, 256> table{};
  for (int c = 0; c < 256; ++c) table[static_cast<std::size_t>(c)] = computeCrossedEdges(c);
  return table;
}
inline constexpr std::array<std::uint16_t, 256> kCrossedEdges = crossedEdgesTable();
}  // namespace detail

/// Bit mask of the edges whose two vertices differ in sign for sign configuration `config` (bit v = vertex v
/// is on the positive side, i.e. value > isovalue). A table lookup: the builders call it for every cell.
constexpr std::uint16_t crossedEdges(std::uint8_t config) {
  return detail::kCrossedEdges[config];
}
/// Bit mask of faces with at least one crossed edge.
std::uint8_t crossedFaces(std::uint8_t config);
/// True if face f has all four edges crossed (diagonal vertices share a sign): its crossings can be paired
/// two ways.
bool isAmbiguousFace(std::uint8_t config, int f);

}  // namespace cip::cube
