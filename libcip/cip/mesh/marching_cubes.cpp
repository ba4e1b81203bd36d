#include "cip/mesh/marching_cubes.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <cmath>
#include <limits>

#include "cip/core/error.h"
#include "cip/mesh/loop_triangulation.h"

namespace cip {

namespace {

/// The loops of one cell with their triangulations.
struct CellTriangulation {
  CellLoops loops;
  std::array<LoopTriangles, 4> loop;
  int triangles = 0, centres = 0;
};

CellTriangulation triangulateCell(const Model& model, std::size_t c) {
  CellTriangulation t;
  t.loops = model.loops(c);
  const ModelCell& cell = model.cells[c];
  const Vec3 origin = model.cellOrigin(c);
  int start = 0;
  for (int l = 0; l < t.loops.numLoops; ++l) {
    const int n = t.loops.loopSize[l];
    std::array<Vec3, 12> local;
    for (int k = 0; k < n; ++k)
      local[k] = model.vertices[model.corners[cell.firstCorner + start + k]].position - origin;
    t.loop[l] = triangulateLoop(n, &t.loops.edges[start], local.data());
    t.triangles += t.loop[l].count;
    if (t.loop[l].kind == LoopTriangulation::CentreFan) ++t.centres;
    start += n;
  }
  return t;
}

}  // namespace

Vec3 indexNormalToWorld(const Vec3& indexNormal, const Vec3& spacing) {
  Vec3 n = indexNormal.cwiseQuotient(spacing);
  double len = n.norm();
  return len > 0 && std::isfinite(len) ? Vec3(n / len) : Vec3::UnitZ();
}

TriangleMesh marchingCubes(const Model& model, const MarchingCubesOptions& options,
                           MarchingCubesStats* stats) {
  TriangleMesh mesh;
  const std::size_t numCells = model.cells.size(), numVertices = model.vertices.size();
  const GridGeometry& geo = model.geometry;
  tbb::task_arena arena(options.threads > 0 ? options.threads : tbb::task_arena::automatic);
  arena.execute([&] {
    // Pass 1: triangles and centre vertices per cell.
    std::vector<std::uint32_t> triCount(numCells), centreCount(numCells);
    std::vector<std::array<std::uint32_t, 3>> kindCount(numCells);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numCells, 512),
                      [&](const tbb::blocked_range<std::size_t>& r) {
                        for (std::size_t c = r.begin(); c != r.end(); ++c) {
                          CellTriangulation t = triangulateCell(model, c);
                          triCount[c] = static_cast<std::uint32_t>(t.triangles);
                          centreCount[c] = static_cast<std::uint32_t>(t.centres);
                          kindCount[c] = {0, 0, 0};
                          for (int l = 0; l < t.loops.numLoops; ++l)
                            ++kindCount[c][static_cast<int>(t.loop[l].kind)];
                        }
                      });
    std::vector<std::uint64_t> triOffset(numCells + 1, 0), centreOffset(numCells + 1, 0);
    MarchingCubesStats s;
    for (std::size_t c = 0; c < numCells; ++c) {
      triOffset[c + 1] = triOffset[c] + triCount[c];
      centreOffset[c + 1] = centreOffset[c] + centreCount[c];
      s.interiorLoops += kindCount[c][0];
      s.upperFaceChordLoops += kindCount[c][1];
      s.centreFanLoops += kindCount[c][2];
    }
    if (numVertices + centreOffset[numCells] > std::numeric_limits<std::uint32_t>::max()) {
      throw Error("marching cubes: too many vertices for 32-bit indices");
    }
    if (stats) *stats = s;
    // Vertices: the isovertices, then the centres.
    const std::size_t totalVertices = numVertices + static_cast<std::size_t>(centreOffset[numCells]);
    mesh.positions.resize(totalVertices);
    mesh.normals.resize(totalVertices);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numVertices, 4096),
                      [&](const tbb::blocked_range<std::size_t>& r) {
                        for (std::size_t v = r.begin(); v != r.end(); ++v) {
                          mesh.positions[v] = geo.indexToWorld(model.vertices[v].position);
                          mesh.normals[v] = indexNormalToWorld(model.vertices[v].normal, geo.spacing);
                        }
                      });
    mesh.triangles.resize(static_cast<std::size_t>(triOffset[numCells]));
    if (options.recordCells) mesh.triangleCell.resize(mesh.triangles.size());
    // Pass 2: write triangles (and centres) at their offsets.
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numCells, 512),
                      [&](const tbb::blocked_range<std::size_t>& r) {
                        for (std::size_t c = r.begin(); c != r.end(); ++c) {
                          CellTriangulation t = triangulateCell(model, c);
                          const ModelCell& cell = model.cells[c];
                          std::size_t tri = static_cast<std::size_t>(triOffset[c]);
                          std::uint32_t centre = static_cast<std::uint32_t>(numVertices + centreOffset[c]);
                          int start = 0;
                          for (int l = 0; l < t.loops.numLoops; ++l) {
                            const int n = t.loops.loopSize[l];
                            std::array<std::uint32_t, 13> id;
                            for (int k = 0; k < n; ++k) id[k] = model.corners[cell.firstCorner + start + k];
                            if (t.loop[l].kind == LoopTriangulation::CentreFan) {
                              Vec3 p = Vec3::Zero(), nrm = Vec3::Zero();
                              for (int k = 0; k < n; ++k) {
                                p += model.vertices[id[k]].position;
                                nrm += model.vertices[id[k]].normal;
                              }
                              mesh.positions[centre] = geo.indexToWorld(p / n);
                              mesh.normals[centre] = indexNormalToWorld(nrm, geo.spacing);
                              id[n] = centre++;
                            }
                            for (int k = 0; k < t.loop[l].count; ++k) {
                              const auto& lt = t.loop[l].triangles[k];
                              mesh.triangles[tri] = {id[lt[0]], id[lt[1]], id[lt[2]]};
                              if (options.recordCells) mesh.triangleCell[tri] = static_cast<std::uint32_t>(c);
                              ++tri;
                            }
                            start += n;
                          }
                        }
                      });
  });
  return mesh;
}

}  // namespace cip
