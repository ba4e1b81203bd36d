/// @file error.h
/// @brief The one exception type libcip throws for bad input (files, parameters, data).
/// Messages are complete sentences meant for the user, e.g. "tooth.nhdr: data file is 1523 bytes short".
#pragma once
#include <stdexcept>
#include <string>

namespace cip {

/// Thrown for any user-facing failure (bad file, bad parameter, bad data). CLIs print what() and exit
/// non-zero.
class Error : public std::runtime_error {
 public:
  explicit Error(const std::string& message) : std::runtime_error(message) {}
};

}  // namespace cip
