/// @file vdb_tree_check.h
/// @brief Walks a grid's tree in a .vdb stream and checks every size stored in it before OpenVDB reads it.
///
/// OpenVDB trusts the sizes in a file's tree: it allocates a stored chunk size before reading the chunk, and
/// in OpenVDB 10 it reads a chunk marked as uncompressed straight into a node's buffer and compares its size
/// only afterwards, so a corrupt file makes it request terabytes or write past the buffer
/// (docs/reliability.md). The walk follows the tree format of OpenVDB's standard trees (root, internal nodes
/// of 32^3 and 16^3 entries, leaves of 8^3 values) in the order OpenVDB reads it: the topology, then the leaf
/// buffers in the order of the root's child table. Each chunk must hold exactly the bytes its node needs and
/// lie inside the file. Used by vdb_reader.cpp; no OpenVDB headers here.
#pragma once
#include <cstdint>
#include <istream>

namespace cip {

/// How a grid's tree is stored.
struct VdbTreeFormat {
  std::uint32_t fileVersion = 0;  ///< the file's format version (the walk needs 222 or later)
  std::uint32_t compression = 0;  ///< the grid's compression flags: zip 1, active mask 2, blosc 4
  int valueBytes = 4;             ///< bytes of one value at full precision
  int halfBytes = 0;              ///< bytes of one value saved as half floats; 0: the type has no half form
  bool fromHalf = false;          ///< the grid is saved as half floats
  /// Leaf buffers use the value masks of the topology (OpenVDB's seekable streams) rather than reading the
  /// copy stored before each buffer.
  bool seekable = false;
};

/// The sizes in the 16-byte header that starts a blosc chunk: the bytes it decompresses to, and the bytes of
/// the chunk blosc reads (blosc trusts this one).
struct BloscSizes {
  std::uint32_t uncompressed = 0, compressed = 0;
};
/// Reads a blosc header (16 bytes, little-endian fields) from the stream.
BloscSizes readBloscHeader(std::istream& is);

/// Walks the tree from the stream's position (its start, after the grid's transform) to the end of its leaf
/// buffers, where it leaves the stream. Throws cip::Error naming the byte offset for a size larger than the
/// rest of the file (`fileSize` bytes), a chunk whose stored size is not the size its node needs, or a format
/// version before 222.
void checkVdbTree(std::istream& is, std::int64_t fileSize, const VdbTreeFormat& format);

}  // namespace cip
