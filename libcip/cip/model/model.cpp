#include "cip/model/model.h"

#include <algorithm>

namespace cip {

const char* toString(PatchMethod method) {
  switch (method) {
    case PatchMethod::Paper:
      return "paper";
    case PatchMethod::Fitted:
      return "fitted";
  }
  return "unknown";
}

CellLoops Model::loops(std::size_t c) const {
  return buildCellLoops(cells[c].config, cells[c].pairing03);
}

CornerPatch Model::patch(std::size_t c, const CellLoops& l) const {
  const ModelCell& cell = cells[c];
  CornerPatch p;
  p.numCorners = cell.numCorners();
  Vec3 origin = cellOrigin(c);
  for (int k = 0; k < p.numCorners; ++k) {
    const IsoVertex& v = vertices[corners[cell.firstCorner + k]];
    p.point[k] = v.position - origin;
    p.normal[k] = v.normal;
    p.weight[k] = v.weight;
    p.edge[k] = l.edges[k];
  }
  p.faceMask = l.faceMask;
  p.faceCoefficient = cell.faceCoefficient;
  p.central = cell.central;
  return p;
}

std::int64_t Model::findCell(std::int64_t i, std::int64_t j, std::int64_t k) const {
  auto key = [](const std::array<std::uint32_t, 3>& x) {
    return std::array<std::uint32_t, 3>{x[2], x[1], x[0]};
  };
  std::array<std::uint32_t, 3> target{static_cast<std::uint32_t>(k), static_cast<std::uint32_t>(j),
                                      static_cast<std::uint32_t>(i)};
  if (i < 0 || j < 0 || k < 0) return -1;
  auto it = std::lower_bound(
      cells.begin(), cells.end(), target,
      [&](const ModelCell& c, const std::array<std::uint32_t, 3>& t) { return key(c.index) < t; });
  if (it == cells.end() || key(it->index) != target) return -1;
  return it - cells.begin();
}

}  // namespace cip
