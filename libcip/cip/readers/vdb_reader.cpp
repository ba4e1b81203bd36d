#include "cip/readers/vdb_reader.h"

#include "cip/core/module_loader.h"

namespace cip {

namespace {

/// OpenVDB is loaded with the module, only when a .vdb file is read.
const VdbReaderModule& openVdb(const std::string& path) {
  return moduleTable<VdbReaderModule>("cip_vdb", "cip_vdb_reader_module", path + ": reading OpenVDB files");
}

}  // namespace

std::vector<VdbGridInfo> listVdbGrids(const std::string& path) {
  return openVdb(path).listGrids(path);
}

SparseVolume readVdb(const std::string& path, const VdbReadOptions& options) {
  return openVdb(path).read(path, options);
}

}  // namespace cip
