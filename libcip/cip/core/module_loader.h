/// @file module_loader.h
/// @brief libcip's optional modules: code that needs a large library is a shared object loaded on first use.
///
/// Reading OpenVDB files (OpenVDB, Boost, Blosc, log4cplus) and DICOM series (GDCM, whose dictionaries are
/// built when it loads), and extract's MPI support (Open MPI), were about 0.12 s of every extract run's
/// start-up, most of it the dynamic linker resolving those libraries' symbols, and a third of the whole run
/// on the bundled volumes. Each now lives in a module (libcip_vdb.so, libcip_dicom.so, libcip_mpi.so) that a
/// program loads only when it reads such a file or runs under mpirun; the functions of vdb_reader.h and
/// dicom_reader.h load theirs themselves.
///
/// Where modules are looked for: the folder named by the environment variable CIP_MODULE_DIR when it is set
/// (and then nowhere else); otherwise `modules/` beside the folder of the program or shared object that holds
/// libcip (BUILD/extract/extract and BUILD/python/cip/_cip.so look in BUILD/modules and
/// BUILD/python/modules), then the build tree's own modules folder.
#pragma once
#include <string>

/// Marks a module's entry point: a C function that returns the module's table of functions.
#define CIP_MODULE_ENTRY extern "C" __attribute__((visibility("default")))

namespace cip {

/// The address of `symbol` in module `name` (file lib<name>.so), loading the module the first time it is
/// asked for (thread-safe; a module stays loaded). Throws cip::Error, starting with `what` (what the module
/// is wanted for, e.g. "x.vdb: reading OpenVDB files"), naming every file tried and why it failed, when no
/// folder holds a module that loads.
void* moduleSymbol(const std::string& name, const char* symbol, const std::string& what);

/// A module's table of functions: calls the entry point `symbol` (`const Table* symbol()`) of module `name`.
template <class Table>
const Table& moduleTable(const std::string& name, const char* symbol, const std::string& what) {
  using Entry = const Table* (*)();
  return *reinterpret_cast<Entry>(moduleSymbol(name, symbol, what))();
}

}  // namespace cip
