// OpenVDB reader: the shared sphere (level set) and smoke (fog) grids as bricks. Checks the global geometry,
// that every cell with an active corner is owned by exactly one brick whose samples match the tree, that the
// brick model is byte-identical to the model of the densified box, and that the sphere's isovertices lie on
// its radius.
#include "cip/readers/vdb_reader.h"

#include <gtest/gtest.h>
#include <openvdb/io/Stream.h>
#include <openvdb/openvdb.h>
#include <sys/resource.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <limits>
#include <map>

#include "cip/core/world_transform.h"
#include "cip/model/model_builder.h"
#include "cip/model/model_file.h"
#include "cip/readers/volume_reader.h"
#include "support/model_bytes.h"
#include "support/sanitized_build.h"
#include "support/volume_files.h"

namespace cip {
namespace {

using test::expectError;
using test::sharedData;

openvdb::FloatGrid::Ptr loadTree(const std::string& path, const std::string& name) {
  openvdb::initialize();
  openvdb::io::File file(path);
  file.open();
  auto grid = openvdb::gridPtrCast<openvdb::FloatGrid>(file.readGrid(name));
  file.close();
  return grid;
}

/// The whole global box of `volume` sampled from the tree (test reference only: small grids).
DenseGrid densify(const SparseVolume& volume, const openvdb::FloatGrid& tree, const openvdb::Coord& lo) {
  DenseGrid g;
  g.allocate(volume.geometry.dims);
  g.geometry = volume.geometry;
  auto acc = tree.getConstAccessor();
  for (std::int64_t k = 0; k < g.geometry.dims[2]; ++k)
    for (std::int64_t j = 0; j < g.geometry.dims[1]; ++j)
      for (std::int64_t i = 0; i < g.geometry.dims[0]; ++i)
        g.at(i, j, k) =
            acc.getValue(lo + openvdb::Coord(static_cast<int>(i), static_cast<int>(j), static_cast<int>(k)));
  return g;
}

/// Checks that bricks own disjoint cells and cover every cell with an active corner, with values from the
/// tree; that each brick keeps an apron of `apron` points where the global grid has them; and that every
/// brick owns a cell with an active corner.
void checkBricks(const SparseVolume& v, const openvdb::FloatGrid& tree, std::int64_t apron = 1) {
  const auto& dims = v.geometry.dims;
  openvdb::CoordBBox active = tree.evalActiveVoxelBoundingBox();
  const openvdb::Coord lo = active.min() - openvdb::Coord(1, 1, 1);
  EXPECT_EQ(dims[0], active.dim()[0] + 2);
  EXPECT_EQ(dims[1], active.dim()[1] + 2);
  EXPECT_EQ(dims[2], active.dim()[2] + 2);
  ASSERT_EQ(v.grids.size(), v.bricks.size());
  // Owner of each owned cell (global cell key -> brick).
  std::map<std::int64_t, std::size_t> owner;
  auto key = [&](std::int64_t i, std::int64_t j, std::int64_t k) { return i + dims[0] * (j + dims[1] * k); };
  for (std::size_t b = 0; b < v.bricks.size(); ++b) {
    const GridBrick& br = v.bricks[b];
    ASSERT_EQ(br.grid, &v.grids[b]);
    const auto& bd = br.grid->geometry.dims;
    for (int a = 0; a < 3; ++a) {
      EXPECT_GE(br.offset[a], 0);
      EXPECT_LE(br.offset[a] + bd[a], dims[a]);
      EXPECT_LT(br.cellBegin[a], br.cellEnd[a]);
      EXPECT_LE(br.cellEnd[a] + 1, bd[a]);
      // Apron: `apron` points before and after the owned cells, or as many as the global grid has.
      EXPECT_EQ(br.cellBegin[a], std::min(apron, br.offset[a] + br.cellBegin[a]));
      EXPECT_EQ(bd[a] - 1 - br.cellEnd[a], std::min(apron, dims[a] - 1 - (br.offset[a] + br.cellEnd[a])));
    }
    // Samples equal the tree's values everywhere in the brick, apron included (spot checks on a lattice).
    auto acc = tree.getConstAccessor();
    for (std::int64_t k = 0; k < bd[2]; k += 3)
      for (std::int64_t j = 0; j < bd[1]; j += 2)
        for (std::int64_t i = 0; i < bd[0]; ++i) {
          openvdb::Coord c =
              lo + openvdb::Coord(static_cast<int>(br.offset[0] + i), static_cast<int>(br.offset[1] + j),
                                  static_cast<int>(br.offset[2] + k));
          ASSERT_EQ(br.grid->at(i, j, k), acc.getValue(c));
        }
    bool ownsActiveCorner = false;
    for (std::int64_t k = br.cellBegin[2]; k < br.cellEnd[2]; ++k)
      for (std::int64_t j = br.cellBegin[1]; j < br.cellEnd[1]; ++j)
        for (std::int64_t i = br.cellBegin[0]; i < br.cellEnd[0]; ++i) {
          std::int64_t gi = br.offset[0] + i, gj = br.offset[1] + j, gk = br.offset[2] + k;
          bool inserted = owner.emplace(key(gi, gj, gk), b).second;
          ASSERT_TRUE(inserted) << "cell owned twice";
          for (int c = 0; c < 8 && !ownsActiveCorner; ++c) {
            openvdb::Coord p =
                lo + openvdb::Coord(static_cast<int>(gi + (c & 1)), static_cast<int>(gj + ((c >> 1) & 1)),
                                    static_cast<int>(gk + ((c >> 2) & 1)));
            ownsActiveCorner = acc.isValueOn(p);
          }
        }
    EXPECT_TRUE(ownsActiveCorner) << "brick " << b << " owns no cell with an active corner";
  }
  // Every active voxel: all 8 cells around it are owned.
  std::int64_t activeCount = 0;
  for (auto it = tree.cbeginValueOn(); it; ++it) {
    ASSERT_TRUE(it.isVoxelValue());
    openvdb::Coord p = it.getCoord() - lo;
    ++activeCount;
    for (int c = 0; c < 8; ++c) {
      std::int64_t ci = p.x() - (c & 1), cj = p.y() - ((c >> 1) & 1), ck = p.z() - ((c >> 2) & 1);
      ASSERT_TRUE(owner.count(key(ci, cj, ck)))
          << "cell around active voxel " << it.getCoord() << " not owned";
    }
  }
  EXPECT_EQ(activeCount, static_cast<std::int64_t>(tree.activeVoxelCount()));
  EXPECT_EQ(static_cast<std::int64_t>(owner.size()), v.ownedCellCount());
}

TEST(VdbReader, ListsGrids) {
  auto grids = listVdbGrids(sharedData("vdb/sphere.vdb"));
  ASSERT_EQ(grids.size(), 1u);
  EXPECT_EQ(grids[0].name, "ls_sphere");
  EXPECT_EQ(grids[0].valueType, "float");
  EXPECT_EQ(grids[0].gridClass, "level set");
}

TEST(VdbReader, SphereLevelSet) {
  const std::string path = sharedData("vdb/sphere.vdb");
  VdbReadOptions o;
  o.brickCells = 16;
  SparseVolume v = readVdb(path, o);
  EXPECT_TRUE(v.isLevelSet);
  EXPECT_NEAR(v.background, 0.15, 1e-3);
  EXPECT_NEAR(v.geometry.spacing[0], 0.05, 1e-8);  // stored as float
  EXPECT_NEAR(v.geometry.spacing[2], 0.05, 1e-8);
  EXPECT_EQ(v.geometry.dims, (std::array<std::int64_t, 3>{127, 127, 127}));
  EXPECT_NEAR(v.geometry.origin[0], -63 * 0.05, 1e-6);  // active box starts at index -62, one point of margin
  EXPECT_NE(v.description.find("ls_sphere"), std::string::npos);
  EXPECT_NE(v.description.find("level set"), std::string::npos);
  EXPECT_EQ(v.dense(), nullptr);
  // Bricks away from the shell (box corners, sphere centre) are left out: fewer than the 8^3 bricks of the
  // box.
  EXPECT_LT(v.bricks.size(), 8u * 8 * 8);
  EXPECT_GT(v.bricks.size(), 100u);
  auto tree = loadTree(path, "ls_sphere");
  checkBricks(v, *tree);

  // The brick model equals the model of the whole box densified, for each reconstruction when the bricks
  // keep the points its reference reads.
  BuildOptions opt;
  opt.isovalue = 0;
  opt.threads = 2;
  Model sparse = buildModel(v.geometry, v.bricks, opt, "sphere");
  DenseGrid whole = densify(v, *tree, tree->evalActiveVoxelBoundingBox().min() - openvdb::Coord(1, 1, 1));
  whole.description = "sphere";
  ASSERT_GT(sparse.cells.size(), 1000u);
  EXPECT_EQ(test::modelBytes(sparse), test::modelBytes(buildModel(whole, opt)));
  {
    opt.reconstruction = Reconstruction::Central8;
    VdbReadOptions wide = o;
    wide.apron = brickApron(opt);
    ASSERT_EQ(wide.apron, 4);
    SparseVolume w = readVdb(path, wide);
    ASSERT_EQ(w.bricks.size(), v.bricks.size());
    checkBricks(w, *tree, wide.apron);
    const auto central8 = test::modelBytes(buildModel(w.geometry, w.bricks, opt, "sphere"));
    EXPECT_EQ(central8, test::modelBytes(buildModel(whole, opt)));
    // With the default apron the bricks extend their own samples, and the model differs near their seams.
    // (The sanitizer run takes that path in FittedPatches.BricksJoinContinuously.)
    if (!test::kSanitizedBuild) {
      EXPECT_NE(central8, test::modelBytes(buildModel(v.geometry, v.bricks, opt, "sphere")));
    }
    opt.reconstruction = Reconstruction::Monotone;
  }

  // Radius from the data: zero crossings of the samples along the three axes through the centre point.
  const DenseGrid& d = whole;
  std::int64_t c = 63;  // global index of world 0 on each axis
  auto crossing = [&](int axis, int dir) {
    std::array<std::int64_t, 3> p{c, c, c};
    double prev = d.at(p[0], p[1], p[2]);
    for (std::int64_t s = 1; s < 63; ++s) {
      p[axis] = c + dir * s;
      double cur = d.at(p[0], p[1], p[2]);
      if ((prev < 0) != (cur < 0))
        return v.geometry.spacing[axis] * (static_cast<double>(s) - 1 + prev / (prev - cur));
      prev = cur;
    }
    return -1.0;
  };
  double r = 0;
  for (int axis = 0; axis < 3; ++axis) {
    double a = crossing(axis, 1), b = crossing(axis, -1);
    ASSERT_GT(a, 0);
    ASSERT_GT(b, 0);
    EXPECT_NEAR(a, b, 0.01);  // centred at the world origin
    r += (a + b) / 6;
  }
  EXPECT_GT(r, 1.0);
  double worst = 0;
  for (const IsoVertex& vx : sparse.vertices) {
    Vec3 w = v.geometry.indexToWorld(vx.position);
    worst = std::max(worst, std::abs(w.norm() - r));
  }
  EXPECT_LT(worst, 0.25 * 0.05) << "radius " << r;  // within a quarter voxel
}

TEST(VdbReader, SmokeFogVolume) {
  const std::string path = sharedData("vdb/smoke.vdb");
  VdbReadOptions o;
  o.gridName = "density";
  o.brickCells = 24;
  SparseVolume v = readVdb(path, o);
  EXPECT_FALSE(v.isLevelSet);
  EXPECT_EQ(v.background, 0);
  EXPECT_NEAR(v.geometry.spacing[1], 0.476, 1e-3);
  EXPECT_EQ(v.geometry.dims, (std::array<std::int64_t, 3>{113, 224, 114}));
  EXPECT_NE(v.description.find("density"), std::string::npos);
  EXPECT_NE(v.description.find("fog"), std::string::npos);
  auto tree = loadTree(path, "density");
  // Active box starts at [1,2,1]: origin is the world position of index (0,1,0), spacing the voxel size.
  openvdb::Vec3d o0 = tree->transform().indexToWorld(openvdb::Vec3d(0, 1, 0));
  openvdb::Vec3d vs = tree->transform().voxelSize();
  for (int a = 0; a < 3; ++a) {
    EXPECT_NEAR(v.geometry.origin[a], o0[a], 1e-9);
    EXPECT_NEAR(v.geometry.spacing[a], vs[a], 1e-12);
  }
  checkBricks(v, *tree);
  BuildOptions opt;
  opt.isovalue = test::kSanitizedBuild ? 3 : 0.1;  // 11,541 cells instead of 224,812 under the sanitizers
  opt.threads = 2;
  Model sparse = buildModel(v.geometry, v.bricks, opt, "smoke");
  DenseGrid whole = densify(v, *tree, tree->evalActiveVoxelBoundingBox().min() - openvdb::Coord(1, 1, 1));
  whole.description = "smoke";
  EXPECT_GT(sparse.cells.size(), 1000u);
  EXPECT_EQ(test::modelBytes(sparse), test::modelBytes(buildModel(whole, opt)));
  // The range is that of the tree's values: its largest active density, and its background (0), which the
  // inactive voxels of the box hold, below every active one.
  float activeMin = std::numeric_limits<float>::infinity(), activeMax = -activeMin;
  for (auto it = tree->cbeginValueOn(); it; ++it) {
    activeMin = std::min(activeMin, *it);
    activeMax = std::max(activeMax, *it);
  }
  EXPECT_GE(activeMin, tree->background());
  auto [lo, hi] = v.range();
  EXPECT_EQ(lo, tree->background());
  EXPECT_EQ(hi, activeMax);
  EXPECT_EQ(lo, *std::min_element(whole.values.begin(), whole.values.end()));
  EXPECT_EQ(hi, *std::max_element(whole.values.begin(), whole.values.end()));
}

TEST(VdbReader, Errors) {
  const std::string sphere = sharedData("vdb/sphere.vdb");
  VdbReadOptions o;
  o.gridName = "density";
  expectError([&] { readVdb(sphere, o); }, {sphere, "no grid named 'density'", "'ls_sphere' (float)"});
  o.gridName = "";
  o.maxBytes = 1 << 20;
  expectError([&] { readVdb(sphere, o); }, {sphere, "MiB"});
  expectError([&] { readVdb(sharedData("tooth.nhdr")); }, {"tooth.nhdr"});
  expectError([&] { readVdb("/nonexistent/x.vdb"); }, {"/nonexistent/x.vdb", "cannot open"});
  expectError([&] { listVdbGrids(sharedData("nucleon.nhdr")); }, {"nucleon.nhdr"});
  test::ScratchDir dir;
  std::string bytes = test::readAll(sphere);
  test::writeAll(dir.file("cut.vdb"), bytes.substr(0, bytes.size() / 2));
  expectError([&] { readVdb(dir.file("cut.vdb")); }, {"cut.vdb", "truncated"});
  // Cut inside the grid's header: the tree's stored offsets lie beyond the end, and the file is rejected
  // before OpenVDB reads the tree (a truncated file once made it take 4.2 GB for 9.7 KB,
  // tests/fuzz/regressions/vdb/openvdb-4gb-from-10kb.vdb).
  rusage before{}, after{};
  getrusage(RUSAGE_SELF, &before);
  test::writeAll(dir.file("head.vdb"), bytes.substr(0, 9694));
  expectError([&] { readVdb(dir.file("head.vdb")); }, {"head.vdb", "is stored up to byte", "truncated"});
  expectError([&] { readVdb(test::sourceFile("tests/fuzz/regressions/vdb/openvdb-4gb-from-10kb.vdb")); },
              {"is stored up to byte 76555", "the file has 9694 bytes"});
  // Strings and metadata values are a 32-bit size and that many bytes, and OpenVDB allocates the size before
  // reading: these files (589 B to 76 KB, found by fuzzing) made it allocate 2-4 GB. Each size is now checked
  // against the rest of the file first, in the file's metadata, in a grid descriptor and in a grid's
  // metadata.
  const std::string regressions = "tests/fuzz/regressions/vdb/";
  expectError([&] { readVdb(test::sourceFile(regressions + "openvdb-4gb-grid-type-name.vdb")); },
              {"a grid type name at byte 79 claims 4294966032 bytes", "the file has 589"});
  expectError([&] { readVdb(test::sourceFile(regressions + "openvdb-4gb-file-metadata-name.vdb")); },
              {"a metadata name at byte 65 claims", "the file has 1213"});
  expectError([&] { readVdb(test::sourceFile(regressions + "openvdb-4gb-instance-parent-name.vdb")); },
              {"an instance parent name at byte 99 claims"});
  expectError([&] { readVdb(test::sourceFile(regressions + "openvdb-2gb-grid-metadata-name.vdb")); },
              {"a metadata name at byte 306 claims 2130706449 bytes"});
  expectError([&] { listVdbGrids(test::sourceFile(regressions + "openvdb-4gb-grid-type-name.vdb")); },
              {"a grid type name at byte 79 claims"});
  expectError([&] { listVdbGrids(test::sourceFile(regressions + "openvdb-2gb-grid-metadata-name.vdb")); },
              {"a metadata name at byte 306 claims"});
  // Inside metadata values: OpenVDB sizes the table for delayed loading by a leaf count and a blosc header
  // inside the value (2 GB for 76 KB files), and reads a number or vector as its own size whatever the
  // value's stored size says, which leaves it reading the following names where these checks did not look.
  expectError([&] { readVdb(test::sourceFile(regressions + "openvdb-2gb-delayed-load-count.vdb")); },
              {"a metadata value of type __delayedload at byte 344 lists 2130706696 leaves"});
  expectError([&] { readVdb(test::sourceFile(regressions + "openvdb-2gb-delayed-load-table.vdb")); },
              {"__delayedload at byte 344 has a compressed table of 2315222784 bytes"});
  expectError([&] { readVdb(test::sourceFile(regressions + "openvdb-misread-int32-metadata.vdb")); },
              {"a metadata value of type int32 at byte 235 has 12 bytes instead of 4"});
  getrusage(RUSAGE_SELF, &after);
  EXPECT_LT(after.ru_maxrss - before.ru_maxrss, 256 * 1024);  // kilobytes
  o.maxBytes = DenseGrid::defaultMaxBytes();
  o.brickCells = 0;
  expectError([&] { readVdb(sphere, o); }, {"brick size"});
  o.brickCells = 16;
  o.apron = 0;
  expectError([&] { readVdb(sphere, o); }, {"apron"});
  o.apron = 65;
  expectError([&] { readVdb(sphere, o); }, {"apron"});
}

TEST(VdbReader, HugeActiveTileIsRefusedBeforeItsBricksAreListed) {
  // One active tile of 4096^3 voxels takes a few bytes in a file and 2 million bricks (700 GB) as dense
  // bricks: the reader stops listing bricks once their samples pass the limit (a corrupt 76 KB file once made
  // it list bricks for 338 MB before the size check).
  openvdb::initialize();
  test::ScratchDir dir;
  auto grid = openvdb::FloatGrid::create(0.0f);
  grid->setName("block");
  grid->fill(openvdb::CoordBBox(openvdb::Coord(0), openvdb::Coord(4095)), 1.0f, true);
  openvdb::io::File(dir.file("t.vdb")).write({grid});
  rusage before{}, after{};
  getrusage(RUSAGE_SELF, &before);
  expectError([&] { readVdb(dir.file("t.vdb")); },
              {"'block' needs more dense bricks than the", "MiB allowed"});
  getrusage(RUSAGE_SELF, &after);
  EXPECT_LT(after.ru_maxrss - before.ru_maxrss, 256 * 1024);  // kilobytes
}

TEST(VdbReader, GridsWithoutActiveVoxelsOrWithRotations) {
  openvdb::initialize();
  test::ScratchDir dir;
  auto empty = openvdb::FloatGrid::create(1.0f);
  empty->setName("empty");
  auto rotated = openvdb::FloatGrid::create(0.0f);
  rotated->setName("rotated");
  rotated->tree().setValue(openvdb::Coord(1, 2, 3), 1.0f);
  openvdb::math::Transform::Ptr xf = openvdb::math::Transform::createLinearTransform(0.5);
  xf->preRotate(0.3, openvdb::math::Z_AXIS);
  rotated->setTransform(xf);
  auto vec = openvdb::Vec3SGrid::create();
  vec->setName("velocity");
  auto dbl = openvdb::DoubleGrid::create(-2.0);
  dbl->setName("dbl");
  dbl->tree().setValue(openvdb::Coord(-5, 0, 7), 3.5);
  dbl->tree().setValue(openvdb::Coord(40, 0, 7),
                       -1.5);  // two far-apart voxels: two separate clusters of bricks
  dbl->setTransform(openvdb::math::Transform::createLinearTransform(2.0));
  auto tiles = openvdb::FloatGrid::create(0.0f);
  tiles->setName("tiles");
  tiles->fill(openvdb::CoordBBox(openvdb::Coord(0), openvdb::Coord(15)), 2.0f,
              true);  // whole leaves: active tiles
  tiles->tree().setValue(openvdb::Coord(-1, 0, 0), 1.0f);
  openvdb::GridPtrVec grids{vec, empty, rotated, dbl, tiles};
  openvdb::io::File(dir.file("g.vdb")).write(grids);

  const std::string path = dir.file("g.vdb");
  VdbReadOptions o;
  o.gridName = "empty";
  expectError([&] { readVdb(path, o); }, {path, "'empty' has no active voxels"});
  o.gridName = "rotated";
  {
    // A rotated grid is placed as its transform says: every grid point sits where OpenVDB puts it, the
    // samples stay in index order.
    const SparseVolume r = readVdb(path, o);
    EXPECT_FALSE(r.geometry.axisAligned());
    EXPECT_NEAR(r.geometry.spacing[0], 0.5, 1e-12);
    const WorldTransform w = WorldTransform::of(r.geometry);
    const openvdb::Coord lo(0, 1, 2);  // the active voxel (1,2,3) and one point of margin
    for (const openvdb::Coord ijk :
         {openvdb::Coord(0, 0, 0), openvdb::Coord(1, 0, 0), openvdb::Coord(0, 1, 0), openvdb::Coord(0, 0, 1),
          openvdb::Coord(2, 1, 2)}) {
      const openvdb::Vec3d p = xf->indexToWorld(lo + ijk);
      const Vec3 q = w.point(r.geometry.indexToWorld(Vec3(ijk.x(), ijk.y(), ijk.z())));
      EXPECT_LT((q - Vec3(p[0], p[1], p[2])).norm(), 1e-12);
    }
    EXPECT_EQ(r.grids[0].at(1, 1, 1), 1.0);
  }
  // A mirrored axis is a flip of the direction (OpenVDB itself refuses to make a singular transform).
  auto mirrored = rotated->deepCopy();
  mirrored->setTransform(openvdb::math::Transform::createLinearTransform(
      openvdb::math::Mat4d(-0.5, 0., 0., 0., 0., 0.5, 0., 0., 0., 0., 0.5, 0., 0., 0., 0., 1.)));
  mirrored->setName("mirrored");
  openvdb::io::File(dir.file("m.vdb")).write(openvdb::GridCPtrVec{mirrored});
  o.gridName = "mirrored";
  const SparseVolume mv = readVdb(dir.file("m.vdb"), o);
  EXPECT_EQ(mv.geometry.direction, Mat3(Vec3(-1, 1, 1).asDiagonal()));
  EXPECT_EQ(mv.geometry.spacing, Vec3(0.5, 0.5, 0.5));
  o.gridName = "velocity";
  expectError([&] { readVdb(path, o); }, {path, "vec3s", "only float and double"});
  o.gridName = "dbl";
  o.brickCells = 8;
  SparseVolume v = readVdb(path, o);
  EXPECT_EQ(v.geometry.dims, (std::array<std::int64_t, 3>{48, 3, 3}));
  EXPECT_EQ(v.geometry.origin, Vec3(-12, -2, 12));
  EXPECT_EQ(v.background, -2.0);
  EXPECT_EQ(v.bricks.size(), 2u);  // the bricks between the two voxels are left out
  EXPECT_EQ(v.grids[0].at(1, 1, 1), 3.5);
  EXPECT_NE(v.description.find("double"), std::string::npos);
  // Active tiles are covered like voxels.
  ASSERT_GT(tiles->tree().activeTileCount(), 0u);
  o.gridName = "tiles";
  SparseVolume t = readVdb(path, o);
  EXPECT_EQ(t.geometry.dims, (std::array<std::int64_t, 3>{19, 18, 18}));
  EXPECT_EQ(t.ownedCellCount(), 18 * 17 * 17);  // every cell has an active corner
  EXPECT_EQ(t.bricks.size(), 27u);
  // A stream without grid offsets (written by io::Stream), and an instance sharing the tree of another grid.
  auto instance = dbl->copyGrid();
  instance->setName("instance");
  {
    std::ofstream out(dir.file("s.vdb"), std::ios::binary);
    openvdb::io::Stream(out).write(openvdb::GridCPtrVec{vec, rotated, dbl});
  }
  openvdb::io::File(dir.file("i.vdb")).write(openvdb::GridCPtrVec{vec, dbl, instance});
  for (const char* file : {"s.vdb", "i.vdb"}) {
    o.gridName = file == std::string("s.vdb") ? "dbl" : "instance";
    SparseVolume w = readVdb(dir.file(file), o);
    EXPECT_EQ(w.geometry.dims, v.geometry.dims) << file;
    EXPECT_EQ(w.bricks.size(), 2u) << file;
    EXPECT_EQ(w.grids[0].values, v.grids[0].values) << file;
    EXPECT_EQ(w.grids[1].values, v.grids[1].values) << file;
  }
  o.gridName = "nothing";
  expectError([&] { readVdb(dir.file("i.vdb"), o); },
              {"no grid named 'nothing'", "'velocity' (vec3s)", "'dbl'", "'instance' (double)"});
  // Default grid: the first float or double grid (the vector grid is skipped), here the empty one.
  expectError([&] { readVdb(path, VdbReadOptions{}); }, {path, "'empty' has no active voxels"});
}

TEST(SparseVolume, FromDenseMatchesDenseBuild) {
  DenseGrid g;
  g.allocate({9, 8, 7});
  g.geometry.spacing = Vec3(0.5, 1, 2);
  for (int k = 0; k < 7; ++k)
    for (int j = 0; j < 8; ++j)
      for (int i = 0; i < 9; ++i) g.at(i, j, k) = std::hypot(i - 4.1, j - 3.7, k - 3.2) - 2.5;
  g.description = "ball";
  BuildOptions opt;
  Model direct = buildModel(g, opt);
  SparseVolume v = fromDense(g);
  ASSERT_NE(v.dense(), nullptr);
  EXPECT_EQ(v.dense()->values, g.values);
  EXPECT_EQ(v.ownedCellCount(), 8 * 7 * 6);
  SparseVolume moved = std::move(v);
  ASSERT_EQ(moved.bricks[0].grid, &moved.grids[0]);
  EXPECT_EQ(serializeModel(buildModel(moved.geometry, moved.bricks, opt, moved.description)),
            serializeModel(direct));
}

}  // namespace
}  // namespace cip
