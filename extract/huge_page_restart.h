// Restarting extract once with glibc's huge-page heap, for large inputs.
#pragma once
#include <string>

namespace cip {

/// glibc backs its heap with transparent huge pages only when told so in the environment at start-up
/// (restartWithHugePageHeap, core/huge_pages.h); libcip advises its largest tables itself, but the many
/// mid-sized vectors of a build still cost a page fault per 4 KiB. On volumes of tens of MB
/// and more that was a fifth of the build (docs/performance.md), so for inputs of at least `minBytes`
/// (the file, or for an NRRD header the data file it names; analytic fields count as their float32 grid,
/// `analyticPoints` * 4) this replaces the process by itself with the tunable set. It returns when there is
/// nothing to do: the tunable is already set, CIP_HUGE_PAGES=0, the input is small, or the restart fails
/// (then the run continues as it is). `argv` must be main's, unchanged.
void restartWithHugePages(char** argv, const std::string& input, double analyticPoints,
                          double minBytes = 16e6);

}  // namespace cip
