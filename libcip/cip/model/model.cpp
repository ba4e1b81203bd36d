#include "cip/model/model.h"

#include <algorithm>
#include <limits>

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

std::pair<Vec3, Vec3> worldBounds(const Model& model, const WorldTransform& world) {
  if (model.cells.empty()) {
    const Vec3 o = world.point(model.geometry.origin);
    return {o, o};
  }
  const GridGeometry& g = model.geometry;
  if (world.isIdentity()) {  // exact corners, no rounding of centres
    Vec3 lo = model.cellOrigin(0), hi = lo;
    for (std::size_t c = 1; c < model.cells.size(); ++c) {
      lo = lo.cwiseMin(model.cellOrigin(c));
      hi = hi.cwiseMax(model.cellOrigin(c));
    }
    return {g.indexToWorld(lo), g.indexToWorld(hi + Vec3::Ones())};
  }
  const Vec3 half = world.linear.cwiseAbs() * (0.5 * g.spacing);  // world half-extent of any cell
  Vec3 lo = Vec3::Constant(std::numeric_limits<double>::infinity()), hi = -lo;
  for (std::size_t c = 0; c < model.cells.size(); ++c) {
    const Vec3 centre = world.point(g.indexToWorld(model.cellOrigin(c) + Vec3::Constant(0.5)));
    lo = lo.cwiseMin(centre - half);
    hi = hi.cwiseMax(centre + half);
  }
  return {lo, hi};
}

}  // namespace cip
