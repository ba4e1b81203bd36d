/// @file vdb_reader.h
/// @brief OpenVDB (.vdb) input: a float or double grid read as a SparseVolume of dense bricks, never
/// densified.
///
/// The global grid spans the active voxels' index bounding box plus one point on every side, so every cell
/// with an active corner lies inside it; geometry.origin is the world position of the box's lowest point,
/// spacing the length of each index axis in the world and direction its unit world direction: any linear
/// transform is placed as OpenVDB places it (rotations, shears, mirrors; docs/coordinates.md); frustum
/// transforms are rejected with a clear error. The global cells are
/// tiled into cubes of `brickCells` cells; a brick is kept only if it owns a cell with an active corner.
/// Brick values come from the tree (inactive points read as the background, or -background inside a level
/// set). Every size stored in the file, down to the value chunks of the grid's tree (vdb_tree_check.h), is
/// checked before OpenVDB reads it. OpenVDB itself is used only in vdb_reader.cpp.
#pragma once
#include <string>
#include <vector>

#include "cip/volume/sparse_volume.h"

namespace cip {

struct VdbReadOptions {
  /// Grid to read; empty = the first grid whose values are float or double.
  std::string gridName;
  /// Cells per brick side (>= 1).
  int brickCells = 32;
  /// Points kept around each brick's owned cells, where the global grid has them (1..64). A build reads up to
  /// brickApron(options) points beyond a cell's corners (model_builder.h): with at least that many, every
  /// brick's references, and so the model, equal those of the whole volume read as one brick.
  int apron = 1;
  /// Limit on the total bytes of brick samples (doubles), checked before any brick is allocated.
  std::size_t maxBytes = DenseGrid::defaultMaxBytes();
};

/// A grid stored in a .vdb file.
struct VdbGridInfo {
  std::string name;
  std::string valueType;  ///< OpenVDB value type name: "float", "double", "vec3s", "bool", ...
  std::string gridClass;  ///< "level set", "fog volume", "staggered", "unknown"
};

/// Lists the grids of a .vdb file (metadata only). Throws cip::Error "<path>: ..." if it cannot be read.
std::vector<VdbGridInfo> listVdbGrids(const std::string& path);

/// Reads one scalar grid of a .vdb file as bricks. Only that grid is loaded (others are skipped by their
/// stored offsets), except in files without offsets, where the grids before it are walked over, and for
/// instanced grids, where every grid is read (then every grid must have a float, double, int32, int64 or vec3
/// tree, the types whose storage is checked). A file that ends early is detected (OpenVDB alone would fill
/// the missing values silently). Throws cip::Error (message starting with the path) for a missing or corrupt
/// file, an unknown grid name (the message lists the file's grids), a grid that is not float or double, a
/// grid without active voxels, an unsupported transform, or bricks over options.maxBytes.
SparseVolume readVdb(const std::string& path, const VdbReadOptions& options = {});

/// What the module libcip_vdb.so (modules/vdb_module.cpp, the only code that uses OpenVDB) gives the two
/// functions above, which load it on first use through its entry point cip_vdb_reader_module
/// (core/module_loader.h).
struct VdbReaderModule {
  std::vector<VdbGridInfo> (*listGrids)(const std::string& path);
  SparseVolume (*read)(const std::string& path, const VdbReadOptions& options);
};

}  // namespace cip
