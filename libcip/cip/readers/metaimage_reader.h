/// @file metaimage_reader.h
/// @brief MetaImage volumes (ITK/VTK's .mha with the data inline, .mhd with the data in other files): header
/// parser and reader placing the grid where the header's TransformMatrix and Offset put it.
///
/// The header is lines of "Key = Value" up to ElementDataFile, which ends it. Fields read: ObjectType
/// (Image), NDims (3, or 4 for a series of frames), DimSize, ElementType (MET_UCHAR, MET_CHAR, MET_USHORT,
/// MET_SHORT, MET_UINT, MET_INT, MET_FLOAT, MET_DOUBLE), ElementSpacing (else ElementSize, else 1), Offset
/// (also spelled Origin or Position), TransformMatrix (also Rotation or Orientation), AnatomicalOrientation
/// (kept for the description only), BinaryDataByteOrderMSB / ElementByteOrderMSB, BinaryData (ASCII data are
/// refused), CompressedData (zlib) and CompressedDataSize, HeaderSize (bytes to skip at the start of each
/// data file; -1: the data are at its end), ElementNumberOfChannels (1) and ElementDataFile: LOCAL (data
/// right after the header), a file name relative to the header, "LIST [nD]" followed by one file name per
/// line, or a pattern with one integer conversion ("slice%03d.raw 1 40 1": first, last, step). Other fields
/// are ignored, as MetaIO does.
///
/// Placement (docs/volumes.md): TransformMatrix lists the direction matrix column after column, as ITK
/// writes it: its first NDims numbers are the world direction of index axis 0, and so on. World = Offset +
/// TransformMatrix * (ElementSpacing * index), in ITK's LPS frame (WorldSpace::LPS), as ITK reads it: ITK
/// ignores AnatomicalOrientation for placement, and so does cip.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "cip/volume/dense_grid.h"
#include "cip/volume/sample_type.h"

namespace cip {

/// What a MetaImage header says about its volume.
struct MetaImageHeader {
  SampleType type = SampleType::UInt8;
  Endian endian = Endian::Little;
  std::int64_t frames = 1;            ///< DimSize[3] of a 4-D image, else 1
  GridGeometry geometry;              ///< dims, origin, spacing, direction; space LPS
  std::string anatomicalOrientation;  ///< as written ("RAI", "???", ...), empty when absent
  bool compressed = false;
  std::int64_t compressedBytes = -1;  ///< CompressedDataSize; -1 when not given
  std::int64_t headerSize = 0;  ///< HeaderSize: bytes skipped at the start of each data file; -1 = at end
  /// The data files in order, resolved against the header's folder; for LOCAL the header file itself.
  std::vector<std::string> dataFiles;
  bool local = false;           ///< ElementDataFile = LOCAL
  std::uint64_t dataStart = 0;  ///< LOCAL: byte after the header's last line
};

/// Parses a MetaImage header held in `text` (it may continue with the data); `path` is the header's file, to
/// which data file names are relative. Pure function, no I/O. Throws cip::Error for a missing or bad field.
MetaImageHeader parseMetaImageHeader(const std::string& text, const std::string& path);

/// Reads and parses the header of `path` (its first MiB at most); errors are prefixed with the path.
MetaImageHeader readMetaImageHeader(const std::string& path);

/// Reads a MetaImage volume placed as the header says. `frame` selects the frame of a 4-D image (-1: the file
/// must hold a single frame). Throws cip::Error (message starting with the path) for a header problem, a
/// missing data file, data that is short or longer than declared, corrupt compressed data, or dims over
/// `maxBytes` of doubles (checked before allocating).
DenseGrid readMetaImage(const std::string& path, std::size_t maxBytes = DenseGrid::defaultMaxBytes(),
                        int frame = -1);

}  // namespace cip
