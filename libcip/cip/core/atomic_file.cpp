#include "cip/core/atomic_file.h"

#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "cip/core/error.h"

namespace cip {

void writeBytes(std::FILE* f, const void* data, std::size_t size) {
  if (size != 0 && std::fwrite(data, 1, size, f) != size) {
    throw Error(std::string("write failed: ") + std::strerror(errno));
  }
}

std::size_t writeFileAtomically(const std::string& path, const std::function<void(std::FILE*)>& write) {
  std::string tmp = path + ".tmpXXXXXX";
  int fd = ::mkstemp(tmp.data());
  if (fd < 0) throw Error(path + ": cannot create a temporary file beside it: " + std::strerror(errno));
  std::FILE* f = ::fdopen(fd, "wb");
  if (!f) {
    ::close(fd);
    ::unlink(tmp.c_str());
    throw Error(path + ": cannot open a temporary file: " + std::strerror(errno));
  }
  auto fail = [&](const std::string& why) {
    std::fclose(f);
    ::unlink(tmp.c_str());
    throw Error(path + ": " + why);
  };
  try {
    write(f);
  } catch (const std::exception& e) {
    fail(e.what());
  }
  if (std::fflush(f) != 0 || ::fsync(::fileno(f)) != 0)
    fail(std::string("write failed: ") + std::strerror(errno));
  long size = std::ftell(f);
  if (std::fclose(f) != 0) {
    ::unlink(tmp.c_str());
    throw Error(path + ": write failed: " + std::strerror(errno));
  }
  ::chmod(tmp.c_str(), 0644);
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    int err = errno;
    ::unlink(tmp.c_str());
    throw Error(path + ": cannot rename the temporary file into place: " + std::strerror(err));
  }
  return size < 0 ? 0 : static_cast<std::size_t>(size);
}

}  // namespace cip
