#include "openvdb_peer.h"

#include <openvdb/openvdb.h>
#include <openvdb/tools/Dense.h>
#include <openvdb/tools/VolumeToMesh.h>
#include <tbb/task_arena.h>

namespace cipbench {

struct OpenVdbPeer::Impl {
  openvdb::FloatGrid::Ptr grid;
};

OpenVdbPeer::OpenVdbPeer(const cip::DenseGrid& g) : impl_(std::make_unique<Impl>()) {
  openvdb::initialize();
  const auto& d = g.geometry.dims;
  openvdb::CoordBBox box(
      openvdb::Coord(0, 0, 0),
      openvdb::Coord(static_cast<int>(d[0] - 1), static_cast<int>(d[1] - 1), static_cast<int>(d[2] - 1)));
  // cip stores x fastest, which is OpenVDB's LayoutXYZ with z fastest reversed: fill explicitly.
  openvdb::tools::Dense<float, openvdb::tools::LayoutZYX> dense(box);
  for (std::int64_t k = 0; k < d[2]; ++k)
    for (std::int64_t j = 0; j < d[1]; ++j)
      for (std::int64_t i = 0; i < d[0]; ++i)
        dense.setValue(openvdb::Coord(static_cast<int>(i), static_cast<int>(j), static_cast<int>(k)),
                       static_cast<float>(g.at(i, j, k)));
  impl_->grid = openvdb::FloatGrid::create(0.0f);
  // Keep every voxel active (tolerance < 0): volumeToMesh then sees exactly the dense samples.
  openvdb::tools::copyFromDense(dense, impl_->grid->tree(), -1.0f);
}

OpenVdbPeer::~OpenVdbPeer() = default;

std::size_t OpenVdbPeer::mesh(double isovalue, int threads) const {
  std::vector<openvdb::Vec3s> points;
  std::vector<openvdb::Vec3I> triangles;
  std::vector<openvdb::Vec4I> quads;
  tbb::task_arena arena(threads > 0 ? threads : tbb::task_arena::automatic);
  arena.execute([&] { openvdb::tools::volumeToMesh(*impl_->grid, points, triangles, quads, isovalue, 0.0); });
  return triangles.size() + quads.size();
}

}  // namespace cipbench
