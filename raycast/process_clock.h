/// @file process_clock.h
/// @brief Seconds since this process started (before the dynamic loader ran), so that start-up - loading
/// the shared libraries and constructing their globals - can be reported beside the command's own phases.
#pragma once

namespace cip::raycast {

/// Wall seconds since the kernel started this process (Linux: /proc/self/stat's start time against the boot
/// clock; its resolution is the kernel's clock tick, typically 10 ms). 0 where that is unavailable.
double secondsSinceProcessStart();

}  // namespace cip::raycast
