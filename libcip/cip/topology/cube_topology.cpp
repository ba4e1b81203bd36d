#include "cip/topology/cube_topology.h"

namespace cip::cube {

int commonFace(int e1, int e2) {
  if (e1 == e2) return -1;
  auto a = edgeFaces(e1), b = edgeFaces(e2);
  for (int fa : a)
    for (int fb : b)
      if (fa == fb) return fa;
  return -1;
}

std::uint8_t crossedFaces(std::uint8_t config) {
  std::uint16_t edges = crossedEdges(config);
  std::uint8_t faces = 0;
  for (int e = 0; e < kEdges; ++e)
    if ((edges >> e) & 1)
      for (int f : edgeFaces(e)) faces = static_cast<std::uint8_t>(faces | (1u << f));
  return faces;
}

bool isAmbiguousFace(std::uint8_t config, int f) {
  std::uint16_t edges = crossedEdges(config);
  for (int k = 0; k < 4; ++k)
    if (!((edges >> faceEdge(f, k)) & 1)) return false;
  return true;
}

}  // namespace cip::cube
