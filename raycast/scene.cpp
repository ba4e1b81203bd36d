#include "scene.h"

#include <cmath>
#include <string>

#include "cip/core/error.h"

namespace cip::raycast {

EmbreeDevice::EmbreeDevice(int threads)
    : device_(rtcNewDevice(threads > 0 ? ("threads=" + std::to_string(threads)).c_str() : nullptr)) {
  if (!device_)
    throw Error("cannot create an Embree device (error " + std::to_string(rtcGetDeviceError(nullptr)) + ")");
  rtcSetDeviceMemoryMonitorFunction(device_, &EmbreeDevice::monitor, this);
}

bool EmbreeDevice::monitor(void* self, ssize_t bytes, bool /*post*/) {
  auto* d = static_cast<EmbreeDevice*>(self);
  const std::int64_t now = d->bytes_.fetch_add(bytes) + bytes;
  std::int64_t peak = d->peak_.load();
  while (now > peak && !d->peak_.compare_exchange_weak(peak, now)) {
  }
  return true;  // never refuse: the render checked its memory before it started
}

EmbreeDevice::~EmbreeDevice() {
  if (device_) rtcReleaseDevice(device_);
}

void EmbreeDevice::check(const char* what) const {
  const RTCError e = rtcGetDeviceError(device_);
  if (e != RTC_ERROR_NONE)
    throw Error(std::string("Embree error ") + std::to_string(static_cast<int>(e)) + " in " + what);
}

float roundUpToFloat(double x) {
  float f = static_cast<float>(x);
  if (static_cast<double>(f) < x) f = std::nextafter(f, std::numeric_limits<float>::infinity());
  return f;
}

float roundDownToFloat(double x) {
  float f = static_cast<float>(x);
  if (static_cast<double>(f) > x) f = std::nextafter(f, -std::numeric_limits<float>::infinity());
  return f;
}

void setEmbreeRay(RTCRay& out, const Ray& ray, double tNear, double tFar) {
  out.org_x = static_cast<float>(ray.origin.x());
  out.org_y = static_cast<float>(ray.origin.y());
  out.org_z = static_cast<float>(ray.origin.z());
  out.dir_x = static_cast<float>(ray.direction.x());
  out.dir_y = static_cast<float>(ray.direction.y());
  out.dir_z = static_cast<float>(ray.direction.z());
  out.tnear = std::max(0.0f, roundDownToFloat(tNear));
  out.tfar = std::isinf(tFar) ? std::numeric_limits<float>::infinity() : roundUpToFloat(tFar);
  out.time = 0;
  out.mask = 0xFFFFFFFFu;
  out.id = 0;
  out.flags = 0;
}

}  // namespace cip::raycast
