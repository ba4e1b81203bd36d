#include "cip/core/module_loader.h"

#include <dlfcn.h>
#include <link.h>

#include <cstdlib>
#include <filesystem>
#include <map>
#include <mutex>
#include <vector>

#include "cip/core/error.h"

namespace cip {

namespace {

/// The program or shared object that holds this code (libcip is a static library): /proc/self/exe for a
/// program, whose link map has no name (dladdr would give argv[0], which need not be a path), and the shared
/// object's own path for a module such as Python's _cip.so.
std::filesystem::path holder() {
  std::error_code ec;
  Dl_info info{};
  link_map* map = nullptr;
  const bool found =
      dladdr1(reinterpret_cast<void*>(&holder), &info, reinterpret_cast<void**>(&map), RTLD_DL_LINKMAP) != 0;
  const char* self = found && map && map->l_name && *map->l_name ? map->l_name : "/proc/self/exe";
  auto path = std::filesystem::canonical(self, ec);
  return ec ? std::filesystem::path() : path;
}

std::vector<std::filesystem::path> moduleDirs() {
  if (const char* dir = std::getenv("CIP_MODULE_DIR"); dir && *dir) return {dir};
  std::vector<std::filesystem::path> dirs;
  const auto self = holder();
  if (!self.empty()) dirs.push_back(self.parent_path().parent_path() / "modules");
  dirs.emplace_back(CIP_MODULE_BUILD_DIR);
  return dirs;
}

}  // namespace

void* moduleSymbol(const std::string& name, const char* symbol, const std::string& what) {
  static std::mutex mutex;
  static std::map<std::string, void*> handles;  // never closed: the module's code may be running
  const std::lock_guard<std::mutex> lock(mutex);
  void*& handle = handles[name];
  std::string tried;
  if (!handle) {
    const std::string file = "lib" + name + ".so";
    for (const auto& dir : moduleDirs()) {
      const auto path = (dir / file).string();
      if (!std::filesystem::exists(path)) {
        tried += "\n  " + path + ": no such file";
        continue;
      }
      handle = dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL);
      if (handle) break;
      const char* why = dlerror();
      tried += "\n  " + path + ": " + (why ? why : "cannot be loaded");
    }
  }
  if (!handle)
    throw Error(what + " needs the module lib" + name +
                ".so, which could not be loaded (set CIP_MODULE_DIR to "
                "the folder that holds it; it is built into BUILD/modules):" +
                tried);
  dlerror();
  void* address = dlsym(handle, symbol);
  if (!address) {
    const char* why = dlerror();
    throw Error(what + ": lib" + name + ".so has no " + symbol + " (" + (why ? why : "not found") +
                "): a module from another build?");
  }
  return address;
}

}  // namespace cip
