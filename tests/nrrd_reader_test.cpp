// NRRD reader: the shared .nhdr volumes, header parsing (type aliases, 4-D with a leading size-1 axis, space
// directions, origin), attached and detached raw, gzip, bzip2, hex and ascii data, several data files (LIST
// and numbered), skips, and the error paths (placement and frames: nrrd_placement_test.cpp).
#include "cip/readers/nrrd_reader.h"

#include <gtest/gtest.h>

#include <filesystem>

#include "cip/readers/volume_reader.h"
#include "support/volume_files.h"

namespace cip {
namespace {

using test::expectError;
using test::sharedData;

std::uint64_t readAllSize(const std::string& path) {
  return std::filesystem::file_size(path);
}

unsigned char byteAt(const std::string& bytes, std::int64_t n) {
  return static_cast<unsigned char>(bytes[n]);
}

TEST(NrrdReader, Tooth) {
  DenseGrid g = readNrrd(sharedData("tooth.nhdr"));
  EXPECT_EQ(g.geometry.dims, (std::array<std::int64_t, 3>{103, 94, 161}));
  EXPECT_EQ(g.geometry.origin, Vec3(-51.5, -47, -80.5));
  EXPECT_EQ(g.geometry.spacing, Vec3::Ones());
  std::string bytes = test::readAll(sharedData("tooth_103x94x161_uint8.raw"));
  for (auto [i, j, k] : {std::array<std::int64_t, 3>{0, 0, 0}, {51, 47, 80}, {102, 93, 160}, {10, 70, 33}}) {
    EXPECT_EQ(g.at(i, j, k), byteAt(bytes, i + 103 * (j + 94 * k))) << i << " " << j << " " << k;
  }
  unsigned char hi = 0;
  for (char c : bytes) hi = std::max(hi, static_cast<unsigned char>(c));
  EXPECT_EQ(g.range().second, hi);
  EXPECT_GE(g.range().first, 0);
  EXPECT_NE(g.description.find("tooth.nhdr"), std::string::npos);
  EXPECT_NE(g.description.find("uint8"), std::string::npos);
}

TEST(NrrdReader, HeadsqInt16WithSpacings) {
  DenseGrid g = readNrrd(sharedData("headsq.nhdr"));
  EXPECT_EQ(g.geometry.dims, (std::array<std::int64_t, 3>{64, 64, 93}));
  EXPECT_EQ(g.geometry.spacing, Vec3(3.2, 3.2, 1.5));
  EXPECT_EQ(g.geometry.origin, Vec3::Zero());
  std::string bytes = test::readAll(sharedData("headsq_64x64x93_int16.raw"));
  for (std::int64_t n : {std::int64_t(0), std::int64_t(200000), std::int64_t(64 * 64 * 93 - 1)}) {
    auto v = static_cast<std::int16_t>(byteAt(bytes, 2 * n) | (byteAt(bytes, 2 * n + 1) << 8));
    EXPECT_EQ(g.values[n], v);
  }
  auto [lo, hi] = g.range();
  EXPECT_LT(lo, 500);
  EXPECT_GT(hi, 1150);
}

TEST(NrrdReader, Nucleon) {
  DenseGrid g = readNrrd(sharedData("nucleon.nhdr"));
  EXPECT_EQ(g.geometry.dims, (std::array<std::int64_t, 3>{41, 41, 41}));
  std::string bytes = test::readAll(sharedData("nucleon_41x41x41_uint8.raw"));
  EXPECT_EQ(g.at(20, 20, 20), byteAt(bytes, 20 + 41 * (20 + 41 * 20)));
  EXPECT_EQ(g.at(3, 7, 11), byteAt(bytes, 3 + 41 * (7 + 41 * 11)));
}

const char* kMinimal =
    "NRRD0004\n"
    "type: %TYPE%\n"
    "dimension: 3\n"
    "sizes: 2 3 4\n"
    "endian: little\n"
    "encoding: raw\n"
    "data file: x.raw\n";

std::string withType(const std::string& type) {
  std::string s = kMinimal;
  s.replace(s.find("%TYPE%"), 6, type);
  return s;
}

TEST(NrrdHeader, TypeAliases) {
  struct Case {
    const char* text;
    SampleType type;
  } cases[] = {{"unsigned char", SampleType::UInt8}, {"uchar", SampleType::UInt8},
               {"uint8_t", SampleType::UInt8},       {"signed char", SampleType::Int8},
               {"int8", SampleType::Int8},           {"short", SampleType::Int16},
               {"short int", SampleType::Int16},     {"signed short int", SampleType::Int16},
               {"ushort", SampleType::UInt16},       {"unsigned short", SampleType::UInt16},
               {"int", SampleType::Int32},           {"signed int", SampleType::Int32},
               {"uint", SampleType::UInt32},         {"unsigned int", SampleType::UInt32},
               {"float", SampleType::Float32},       {"double", SampleType::Float64}};
  for (const auto& c : cases) EXPECT_EQ(parseNrrdHeader(withType(c.text)).type, c.type) << c.text;
  expectError([] { parseNrrdHeader(withType("quaternion")); }, {"line 2", "quaternion"});
  expectError([] { parseNrrdHeader(withType("block")); }, {"block", "not supported"});
  expectError([] { parseNrrdHeader(withType("long long")); }, {"not supported"});
}

TEST(NrrdHeader, FieldsAndDefaults) {
  NrrdHeader h = parseNrrdHeader(withType("float"));
  EXPECT_EQ(h.version, 4);
  EXPECT_EQ(h.dims, (std::array<std::int64_t, 3>{2, 3, 4}));
  EXPECT_EQ(h.spacing, Vec3::Ones());
  EXPECT_EQ(h.origin, Vec3::Zero());
  EXPECT_EQ(h.dataFiles, std::vector<std::string>{"x.raw"});
  EXPECT_FALSE(h.attached);

  h = parseNrrdHeader(
      "NRRD0005\r\n# comment\r\ntype: short\r\ndimension: 4\r\nsizes: 1 5 6 7\r\n"
      "space: right-anterior-superior\r\nspace directions: none (0.5,0,0) (0, -2 ,0) (0,0,1.25)\r\n"
      "space origin: (1.5, -2,3e1)\r\nkinds: scalar domain domain domain\r\nendian: big\r\nencoding: gz\r\n"
      "byte skip: 3\r\nline skip: 2\r\nmy key:=my value\r\n\r\nBINARY\x00\x01");
  EXPECT_EQ(h.dims, (std::array<std::int64_t, 3>{5, 6, 7}));
  EXPECT_EQ(h.spacing, Vec3(0.5, 2, 1.25));
  EXPECT_EQ(h.direction, Mat3(Vec3(1, -1, 1).asDiagonal()));  // the negative y direction flips that axis
  EXPECT_EQ(h.space, WorldSpace::RAS);
  EXPECT_EQ(h.origin, Vec3(1.5, -2, 30));
  EXPECT_EQ(h.endian, Endian::Big);
  EXPECT_EQ(h.encoding, NrrdEncoding::Gzip);
  EXPECT_EQ(h.byteSkip, 3);
  EXPECT_EQ(h.lineSkip, 2);
  EXPECT_TRUE(h.attached);
  EXPECT_EQ(h.headerBytes,
            std::string_view(
                "NRRD0005\r\n# comment\r\ntype: short\r\ndimension: 4\r\nsizes: 1 5 6 7\r\n"
                "space: right-anterior-superior\r\nspace directions: none (0.5,0,0) (0, -2 ,0) "
                "(0,0,1.25)\r\nspace origin: (1.5, -2,3e1)\r\nkinds: scalar domain domain domain\r\n"
                "endian: big\r\nencoding: gz\r\nbyte skip: 3\r\nline skip: 2\r\nmy key:=my value\r\n\r\n")
                .size());

  h = parseNrrdHeader(
      "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 2 2 2\nspacings: 0.1 0.2 0.3\ncontent: a:=b\n"
      "encoding: raw\ndatafile: a b.raw\n");
  EXPECT_EQ(h.spacing, Vec3(0.1, 0.2, 0.3));
  EXPECT_EQ(h.dataFiles, std::vector<std::string>{"a b.raw"});
}

TEST(NrrdHeader, CorruptHeaders) {
  auto bad = [](const std::string& text, std::vector<std::string> parts) {
    expectError([&] { parseNrrdHeader(text); }, parts);
  };
  const std::string head = "NRRD0004\ntype: uint8\n";
  const std::string tail = "encoding: raw\ndata file: x.raw\n";
  bad("", {"empty"});
  bad("P6\n1 1\n", {"not a NRRD file"});
  bad("NRRD0009\n", {"not a NRRD file"});
  bad(std::string(100000, '\x01'), {"not a NRRD file"});
  bad(head + "dimension 3\n", {"line 3", "expected 'field: value'"});
  bad(head + "dimension: 3\ndimension: 3\n", {"line 4", "twice"});
  bad(head + "dimension: 2\nsizes: 4 4\n" + tail, {"line 3", "dimension 2"});
  bad(head + "dimension: 5\nsizes: 1 1 4 4 4\n" + tail, {"dimension 5"});
  bad(head + "dimension: 4\nsizes: 3 4 4 4\n" + tail, {"line 4", "3x4x4x4", "not spatial"});
  bad(head + "dimension: 3\nsizes: 4 4\n" + tail, {"sizes has 2 entries"});
  bad(head + "dimension: 3\nsizes: 4 -4 4\n" + tail, {"at least 1"});
  bad(head + "dimension: 3\nsizes: 4 four 4\n" + tail, {"'four' is not an integer"});
  bad(head + "dimension: 3\nsizes: 4 4 4\nspace directions: (1,0,0) (0,0.7,0.7) (0,1.4,1.4)\n" + tail,
      {"line 5", "singular"});
  bad(head + "dimension: 3\nsizes: 4 4 4\nspace directions: (1,0,0) (0,1,0) (0,0,1\n" + tail,
      {"parenthesis"});
  bad(head + "dimension: 3\nsizes: 4 4 4\nspace directions: (1,0) (0,1) (0,0)\n" + tail, {"3 components"});
  bad(head + "dimension: 3\nsizes: 4 4 4\nspace origin: (1,2)\n" + tail, {"space origin"});
  bad(head + "dimension: 3\nsizes: 4 4 4\nspacings: 1 0 1\n" + tail, {"spacing"});
  bad(head + "dimension: 3\nsizes: 4 4 4\nencoding: morse\ndata file: x\n", {"unknown encoding 'morse'"});
  bad(head + "dimension: 3\nsizes: 4 4 4\nencoding: raw\n", {"no 'data file'"});
  bad(head + "dimension: 3\nsizes: 4 4 4\nencoding: raw\ndata file: LIST\n", {"LIST names no files"});
  bad(head + "dimension: 3\nsizes: 4 4 4\nencoding: raw\ndata file: LIST 2\na\nb\n",
      {"subdimension 2 needs 4 data files", "names 2"});
  bad(head + "dimension: 3\nsizes: 4 4 4\nencoding: raw\ndata file: s%03d%d.raw 1 4 1\n", {"more than one"});
  bad(head + "dimension: 3\nsizes: 4 4 4\nencoding: raw\ndata file: s%s.raw 1 4 1\n", {"integer conversion"});
  bad(head + "dimension: 3\nsizes: 4 4 4\nencoding: raw\ndata file: s%d.raw 4 1 1\n",
      {"not a valid sequence"});
  bad(head + "dimension: 3\nsizes: 4 4 4\nencoding: raw\ndata file: s%d.raw 1 4 0\n",
      {"not a valid sequence"});
  bad(head + "dimension: 3\nsizes: 4 4 4\nencoding: raw\ndata file: s%d.raw 1 999999999 1\n",
      {"numbered files, more than"});
  bad(head + "dimension: 3\nsizes: 4 4 4\n", {"no 'encoding'"});
  bad("NRRD0004\ntype: int16\ndimension: 3\nsizes: 4 4 4\n" + tail, {"no 'endian'"});
  bad(head + "sizes: 4 4 4\n" + tail, {"no 'dimension'"});
  bad(head + "dimension: 3\nsizes: 4 4 4\nbyte skip: -2\n" + tail, {"byte skip"});
  bad(head + "dimension: 3\nsizes: 4 4 4\nbyte skip: -1\nencoding: gzip\ndata file: x\n", {"byte skip -1"});
  bad(head + "dimension: 3\nsizes: 4 4 4\n" + tail + std::string("bad\0line\n", 9), {"binary data"});
  bad(head + std::string(kNrrdMaxLineBytes + 10, 'a') + "\n", {"line 3", "longer than"});
  std::string longHeader = head;
  while (longHeader.size() <= kNrrdMaxHeaderBytes)
    longHeader += "# padding padding padding padding padding\n";
  bad(longHeader + "\n", {"header longer than 1 MiB"});
}

/// A 3x2x2 int16 big-endian volume with values 100*i - 7*j + 1000*k - 1500.
std::string payload() {
  std::string bytes;
  for (int k = 0; k < 2; ++k)
    for (int j = 0; j < 2; ++j)
      for (int i = 0; i < 3; ++i) {
        auto v = static_cast<std::uint16_t>(static_cast<std::int16_t>(100 * i - 7 * j + 1000 * k - 1500));
        bytes += static_cast<char>(v >> 8);
        bytes += static_cast<char>(v & 0xff);
      }
  return bytes;
}

void expectPayload(const DenseGrid& g) {
  ASSERT_EQ(g.geometry.dims, (std::array<std::int64_t, 3>{3, 2, 2}));
  for (int k = 0; k < 2; ++k)
    for (int j = 0; j < 2; ++j)
      for (int i = 0; i < 3; ++i) EXPECT_EQ(g.at(i, j, k), 100 * i - 7 * j + 1000 * k - 1500);
}

const std::string kHead = "NRRD0004\ntype: int16\ndimension: 3\nsizes: 3 2 2\nendian: big\n";

TEST(NrrdReader, AttachedRawAndGzip) {
  test::ScratchDir dir;
  test::writeAll(dir.file("a.nrrd"), kHead + "encoding: raw\n\n" + payload());
  expectPayload(readNrrd(dir.file("a.nrrd")));
  test::writeAll(dir.file("g.nrrd"), kHead + "encoding: gzip\n\n" + test::gzipBytes(payload()));
  expectPayload(readNrrd(dir.file("g.nrrd")));
  // gzip with byte skip (counted in inflated bytes).
  test::writeAll(dir.file("gs.nrrd"),
                 kHead + "encoding: gzip\nbyte skip: 5\n\n" + test::gzipBytes("12345" + payload()));
  expectPayload(readNrrd(dir.file("gs.nrrd")));
}

TEST(NrrdReader, LargeGzipDetachedMultiMemberAndZlib) {
  test::ScratchDir dir;
  const std::string raw = test::readAll(sharedData("tooth_103x94x161_uint8.raw"));
  const std::string head = "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 103 94 161\nencoding: gzip\n";
  DenseGrid reference = readNrrd(sharedData("tooth.nhdr"));
  // Detached gzip file larger than the inflater's input and output buffers.
  test::writeAll(dir.file("t.raw.gz"), test::gzipBytes(raw));
  test::writeAll(dir.file("t.nhdr"), head + "data file: t.raw.gz\n");
  EXPECT_EQ(readNrrd(dir.file("t.nhdr")).values, reference.values);
  // Two concatenated gzip members (as written by parallel gzip tools).
  const std::size_t half = raw.size() / 2 + 7;
  test::writeAll(dir.file("m.nrrd"),
                 head + "\n" + test::gzipBytes(raw.substr(0, half)) + test::gzipBytes(raw.substr(half)));
  EXPECT_EQ(readNrrd(dir.file("m.nrrd")).values, reference.values);
  // A zlib stream (no gzip wrapper) is accepted too.
  std::string z(compressBound(static_cast<uLong>(raw.size())), '\0');
  uLongf zn = static_cast<uLongf>(z.size());
  ASSERT_EQ(compress2(reinterpret_cast<Bytef*>(z.data()), &zn, reinterpret_cast<const Bytef*>(raw.data()),
                      static_cast<uLong>(raw.size()), 6),
            Z_OK);
  z.resize(zn);
  test::writeAll(dir.file("z.nrrd"), head + "\n" + z);
  EXPECT_EQ(readNrrd(dir.file("z.nrrd")).values, reference.values);
}

TEST(NrrdReader, AsciiData) {
  test::ScratchDir dir;
  const std::string head = "NRRD0004\ntype: float\ndimension: 3\nsizes: 3 2 2\nencoding: ascii\n";
  std::string text;
  for (int k = 0; k < 2; ++k)
    for (int j = 0; j < 2; ++j)
      for (int i = 0; i < 3; ++i)
        text += std::to_string(100 * i - 7 * j + 1000 * k - 1500) + (i == 2 ? "\n" : ", ");
  test::writeAll(dir.file("a.nrrd"), head + "\n" + text);
  expectPayload(readNrrd(dir.file("a.nrrd")));
  test::writeAll(dir.file("a.txt"), "a comment line\n" + text + "\n\n");
  test::writeAll(dir.file("d.nhdr"), head + "line skip: 1\ndata file: a.txt\n");
  expectPayload(readNrrd(dir.file("d.nhdr")));
  test::writeAll(dir.file("more.nrrd"), head + "\n" + text + " 5");
  expectError([&] { readNrrd(dir.file("more.nrrd")); }, {"more.nrrd", "more than the 12 values"});
  test::writeAll(dir.file("less.nrrd"), head + "\n" + text.substr(0, text.size() / 2) + "          ");
  expectError([&] { readNrrd(dir.file("less.nrrd")); }, {"less.nrrd", "of 12 values"});
  test::writeAll(dir.file("nan.nrrd"), head + "\n" + "1 2 3 4 5 6 7 8 9 10 11 twelve");
  expectError([&] { readNrrd(dir.file("nan.nrrd")); }, {"nan.nrrd", "value 12 ('twelve')"});
  test::writeAll(dir.file("tiny.nrrd"), head + "\n" + "1 2");
  expectError([&] { readNrrd(dir.file("tiny.nrrd")); }, {"tiny.nrrd", "cannot hold the 12 values"});
}

TEST(NrrdReader, DetachedWithSkips) {
  test::ScratchDir dir;
  test::writeAll(dir.file("d.raw"), "line one\nline two\nXYZ" + payload());
  test::writeAll(dir.file("d.nhdr"), kHead + "encoding: raw\nline skip: 2\nbyte skip: 3\ndata file: d.raw\n");
  expectPayload(readNrrd(dir.file("d.nhdr")));
  test::writeAll(dir.file("e.raw"), "any header of any length" + payload());
  test::writeAll(dir.file("e.nhdr"), kHead + "encoding: raw\nbyte skip: -1\ndata file: e.raw\n");
  expectPayload(readNrrd(dir.file("e.nhdr")));
  test::writeAll(dir.file("f.nhdr"), kHead + "encoding: raw\nline skip: 9\ndata file: d.raw\n");
  expectError([&] { readNrrd(dir.file("f.nhdr")); }, {"line skip 9"});
}

TEST(NrrdReader, DataErrors) {
  test::ScratchDir dir;
  const std::string p = payload();
  // Raw data short or long.
  test::writeAll(dir.file("short.nrrd"), kHead + "encoding: raw\n\n" + p.substr(0, p.size() - 4));
  expectError([&] { readNrrd(dir.file("short.nrrd")); }, {"short.nrrd", "4 bytes short", "24 bytes"});
  test::writeAll(dir.file("long.nrrd"), kHead + "encoding: raw\n\n" + p + "!!");
  expectError([&] { readNrrd(dir.file("long.nrrd")); }, {"long.nrrd", "2 bytes longer"});
  // Missing detached file.
  test::writeAll(dir.file("m.nhdr"), kHead + "encoding: raw\ndata file: nowhere.raw\n");
  expectError([&] { readNrrd(dir.file("m.nhdr")); }, {"m.nhdr", "nowhere.raw", "cannot open"});
  // Not gzip at all.
  test::writeAll(dir.file("bad.nrrd"), kHead + "encoding: gzip\n\n" + p);
  expectError([&] { readNrrd(dir.file("bad.nrrd")); }, {"bad.nrrd", "corrupt compressed data"});
  // Gzip that inflates past the declared size (a large stream: stopped right after the declared bytes).
  test::writeAll(dir.file("big.nrrd"),
                 kHead + "encoding: gzip\n\n" + test::gzipBytes(p + std::string(50 << 20, 'z')));
  expectError([&] { readNrrd(dir.file("big.nrrd")); },
              {"big.nrrd", "continues past its declared size of 24 bytes"});
  // Gzip that inflates to less.
  test::writeAll(dir.file("less.nrrd"), kHead + "encoding: gzip\n\n" + test::gzipBytes(p.substr(0, 10)));
  expectError([&] { readNrrd(dir.file("less.nrrd")); }, {"less.nrrd", "ends after 10 of 24 bytes"});
  // Truncated gzip stream.
  std::string gz = test::gzipBytes(p + std::string(1000, 'q'));
  test::writeAll(dir.file("cut.nrrd"), kHead + "encoding: gzip\n\n" + gz.substr(0, gz.size() / 2));
  expectError([&] { readNrrd(dir.file("cut.nrrd")); }, {"cut.nrrd"});
  // Header only, missing file.
  expectError([&] { readNrrd(dir.file("none.nrrd")); }, {"none.nrrd", "cannot open"});
  // Corrupt header line reported with the path.
  test::writeAll(dir.file("c.nhdr"), "NRRD0004\ntype: uint8\nthis is not a field\n");
  expectError([&] { readNrrd(dir.file("c.nhdr")); }, {"c.nhdr", "line 3"});
}

TEST(NrrdReader, Bzip2AndHex) {
  test::ScratchDir dir;
  const std::string p = payload();
  test::writeAll(dir.file("b.nrrd"), kHead + "encoding: bzip2\n\n" + test::bzip2Bytes(p));
  expectPayload(readNrrd(dir.file("b.nrrd")));
  // Two concatenated streams, byte skip counted in decompressed bytes, detached.
  test::writeAll(dir.file("b.raw.bz2"),
                 test::bzip2Bytes("abc" + p.substr(0, 7)) + test::bzip2Bytes(p.substr(7)));
  test::writeAll(dir.file("b.nhdr"), kHead + "encoding: bz2\nbyte skip: 3\ndata file: b.raw.bz2\n");
  expectPayload(readNrrd(dir.file("b.nhdr")));
  // A large stream against the reference volume.
  const std::string raw = test::readAll(sharedData("tooth_103x94x161_uint8.raw"));
  test::writeAll(
      dir.file("t.nrrd"),
      "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 103 94 161\nencoding: bzip2\n\n" + test::bzip2Bytes(raw));
  EXPECT_EQ(readNrrd(dir.file("t.nrrd")).values, readNrrd(sharedData("tooth.nhdr")).values);
  // Hex: two digits per byte, blanks anywhere between bytes.
  std::string hex;
  const char* digits = "0123456789abcdef";
  for (std::size_t n = 0; n < p.size(); ++n) {
    hex += digits[byteAt(p, static_cast<std::int64_t>(n)) >> 4];
    hex += digits[byteAt(p, static_cast<std::int64_t>(n)) & 15];
    hex += n % 5 == 4 ? "\n" : "";
  }
  test::writeAll(dir.file("h.nrrd"), kHead + "encoding: hex\n\n" + hex + "\n");
  expectPayload(readNrrd(dir.file("h.nrrd")));
  test::writeAll(dir.file("hx.nrrd"), kHead + "encoding: hex\n\n" + hex.substr(0, 6) + "zz" + hex.substr(8));
  expectError([&] { readNrrd(dir.file("hx.nrrd")); }, {"hx.nrrd", "'z'", "not a hex digit"});
  test::writeAll(dir.file("hl.nrrd"), kHead + "encoding: hex\n\n" + hex + "ab");
  expectError([&] { readNrrd(dir.file("hl.nrrd")); }, {"hl.nrrd", "continues past its declared size"});
}

TEST(NrrdReader, HostileBzip2) {
  test::ScratchDir dir;
  const std::string p = payload();
  // Not bzip2 at all.
  test::writeAll(dir.file("n.nrrd"), kHead + "encoding: bzip2\n\n" + p);
  expectError([&] { readNrrd(dir.file("n.nrrd")); }, {"n.nrrd", "corrupt compressed data", "bzip2"});
  // A flipped byte inside the stream: the block CRC or the Huffman data fails.
  std::string bz = test::bzip2Bytes(p + std::string(5000, 'x'));
  bz[bz.size() / 2] = static_cast<char>(bz[bz.size() / 2] ^ 0x55);
  test::writeAll(dir.file("c.nrrd"),
                 "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 5024 1 1\nencoding: bzip2\n\n" + bz);
  expectError([&] { readNrrd(dir.file("c.nrrd")); }, {"c.nrrd", "corrupt compressed data"});
  // Decompresses far past the declared size: stopped right after it.
  test::writeAll(dir.file("big.nrrd"),
                 kHead + "encoding: bzip2\n\n" + test::bzip2Bytes(p + std::string(50 << 20, 'z')));
  expectError([&] { readNrrd(dir.file("big.nrrd")); },
              {"big.nrrd", "continues past its declared size of 24 bytes"});
  // Decompresses to less; truncated; empty.
  test::writeAll(dir.file("less.nrrd"), kHead + "encoding: bzip2\n\n" + test::bzip2Bytes(p.substr(0, 10)));
  expectError([&] { readNrrd(dir.file("less.nrrd")); }, {"less.nrrd", "ends after 10 of 24 bytes"});
  std::string cut = test::bzip2Bytes(p + std::string(3000, 'q'));
  test::writeAll(dir.file("cut.nrrd"), kHead + "encoding: bzip2\n\n" + cut.substr(0, cut.size() / 2));
  expectError([&] { readNrrd(dir.file("cut.nrrd")); }, {"cut.nrrd"});
  test::writeAll(dir.file("e.nrrd"), kHead + "encoding: bzip2\n\n");
  expectError([&] { readNrrd(dir.file("e.nrrd")); }, {"e.nrrd", "truncated"});
}

/// The payload split into `parts` equal pieces.
std::vector<std::string> pieces(int parts) {
  const std::string p = payload();
  std::vector<std::string> out;
  const std::size_t n = p.size() / static_cast<std::size_t>(parts);
  for (int i = 0; i < parts; ++i) out.push_back(p.substr(static_cast<std::size_t>(i) * n, n));
  return out;
}

TEST(NrrdReader, SeveralDataFiles) {
  test::ScratchDir dir;
  std::filesystem::create_directory(dir.file("sub"));
  // LIST: one file per slice (k), with a subdimension, names relative to the header's folder.
  auto two = pieces(2);
  test::writeAll(dir.file("sub/zero.raw"), two[0]);
  test::writeAll(dir.file("one.raw"), two[1]);
  test::writeAll(dir.file("l.nhdr"), kHead + "encoding: raw\ndata file: LIST 2\nsub/zero.raw\none.raw\n");
  expectPayload(readNrrd(dir.file("l.nhdr")));
  EXPECT_EQ(nrrdDataPaths(dir.file("l.nhdr"), readNrrdHeader(dir.file("l.nhdr"))),
            (std::vector<std::string>{dir.file("sub/zero.raw"), dir.file("one.raw")}));
  EXPECT_EQ(volumeFileBytes(dir.file("l.nhdr")), readAllSize(dir.file("l.nhdr")) + payload().size());
  // A numbered format, counting down, each file gzip-compressed with its own byte skip.
  auto four = pieces(4);
  for (const auto& [name, piece] :
       {std::pair{"s009.gz", 0}, {"s006.gz", 1}, {"s003.gz", 2}, {"s000.gz", 3}}) {
    test::writeAll(dir.file(name), test::gzipBytes("#" + four[static_cast<std::size_t>(piece)]));
  }
  test::writeAll(dir.file("f.nhdr"), kHead + "encoding: gzip\nbyte skip: 1\ndata file: s%03d.gz 9 0 -3\n");
  expectPayload(readNrrd(dir.file("f.nhdr")));
  // Ascii across files.
  test::writeAll(dir.file("a1.txt"), "-1500 -1400 -1300 -1507 -1407 -1307\n");
  test::writeAll(dir.file("a2.txt"), "-500 -400 -300 -507 -407 -307");
  test::writeAll(dir.file("a.nhdr"),
                 "NRRD0004\ntype: short\ndimension: 3\nsizes: 3 2 2\nencoding: ascii\n"
                 "data file: a%d.txt 1 2 1 2\n");
  expectPayload(readNrrd(dir.file("a.nhdr")));
  // A missing file of the list, a file of the wrong size, files that cannot share the data equally.
  test::writeAll(dir.file("m.nhdr"), kHead + "encoding: raw\ndata file: LIST\nsub/zero.raw\ngone.raw\n");
  expectError([&] { readNrrd(dir.file("m.nhdr")); }, {"m.nhdr", "gone.raw", "cannot open"});
  test::writeAll(dir.file("w.nhdr"), kHead + "encoding: raw\ndata file: LIST\nsub/zero.raw\nl.nhdr\n");
  expectError([&] { readNrrd(dir.file("w.nhdr")); }, {"l.nhdr", "bytes"});
  test::writeAll(dir.file("u.nhdr"),
                 kHead + "encoding: raw\ndata file: LIST\none.raw\none.raw\none.raw\none.raw\none.raw\n");
  expectError([&] { readNrrd(dir.file("u.nhdr")); },
              {"u.nhdr", "5 data files cannot hold equal parts of 12"});
}

TEST(NrrdReader, HugeDimsFailBeforeAllocating) {
  test::ScratchDir dir;
  test::writeAll(
      dir.file("o.nhdr"),
      "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 4294967296 4294967296 4294967296\nencoding: raw\n"
      "data file: o.raw\n");
  expectError([&] { readNrrd(dir.file("o.nhdr")); }, {"o.nhdr", "overflow 64 bits"});
  test::writeAll(dir.file("m.nhdr"),
                 "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 1048576 1048576 1024\nencoding: raw\n"
                 "data file: m.raw\n");
  expectError([&] { readNrrd(dir.file("m.nhdr")); }, {"m.nhdr", "MiB", "1048576x1048576x1024"});
  expectError([&] { readNrrd(sharedData("tooth.nhdr"), {1 << 20}); }, {"tooth.nhdr", "MiB"});
}

}  // namespace
}  // namespace cip
