#include "huge_page_restart.h"

#include <algorithm>

#include "cip/core/huge_pages.h"
#include "cip/readers/volume_reader.h"

namespace cip {

void restartWithHugePages(char** argv, const std::string& input, double analyticPoints, double minBytes) {
  if (std::max(static_cast<double>(volumeFileBytes(input)), analyticPoints * 4) < minBytes) return;
  restartWithHugePageHeap(argv);
}

}  // namespace cip
