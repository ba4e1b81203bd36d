#include "cip/reference/reconstruction.h"

#include "cip/core/error.h"

namespace cip {

const char* toString(Reconstruction kind) {
  switch (kind) {
    case Reconstruction::Central8:
      return "central8";
    case Reconstruction::Auto:
      return "auto";
    case Reconstruction::Mask:
      return "mask";
    case Reconstruction::Monotone:
      break;
  }
  return "monotone";
}

Reconstruction parseReconstruction(const std::string& text) {
  if (text == "monotone") return Reconstruction::Monotone;
  if (text == "central8") return Reconstruction::Central8;
  if (text == "auto") return Reconstruction::Auto;
  if (text == "mask") return Reconstruction::Mask;
  throw Error("unknown reconstruction '" + text + "' (expected auto, monotone, central8 or mask)");
}

}  // namespace cip
