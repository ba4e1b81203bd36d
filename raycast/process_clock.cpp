#include "process_clock.h"

#include <time.h>
#include <unistd.h>

#include <cstdio>
#include <fstream>
#include <iterator>
#include <string>

namespace cip::raycast {

double secondsSinceProcessStart() {
#if defined(__linux__)
  std::ifstream in("/proc/self/stat");
  const std::string stat((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  // Field 2 (the command name) may hold spaces and parentheses: the fields after it start after the last ')'.
  const auto close = stat.rfind(')');
  if (close == std::string::npos) return 0;
  unsigned long long start = 0;
  // Fields 3..21 are skipped; field 22 is the start time in clock ticks after boot.
  if (std::sscanf(stat.c_str() + close + 1,
                  " %*c %*d %*d %*d %*d %*d %*u %*u %*u %*u %*u %*u %*u %*d %*d %*d %*d %*d %*d %llu",
                  &start) != 1)
    return 0;
  const long ticks = sysconf(_SC_CLK_TCK);
  timespec now{};
  if (ticks <= 0 || clock_gettime(CLOCK_BOOTTIME, &now) != 0) return 0;
  const double seconds = static_cast<double>(now.tv_sec) + 1e-9 * static_cast<double>(now.tv_nsec) -
                         static_cast<double>(start) / static_cast<double>(ticks);
  return seconds > 0 ? seconds : 0;
#else
  return 0;
#endif
}

}  // namespace cip::raycast
