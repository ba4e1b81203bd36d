// A model of an analytic field sampled at N cells per axis, with the field's own isovalue and the given
// construction or normals: the common fixture of the model file, ray and bound tests.
#pragma once
#include <string>

#include "cip/model/model_builder.h"
#include "cip/volume/analytic_field.h"

namespace cip::test {

inline Model fieldModel(const std::string& field, int n, PatchMethod method) {
  const auto f = makeAnalyticField(field);
  BuildOptions o;
  o.isovalue = f->defaultIsovalue();
  o.method = method;
  return buildModel(sampleField(*f, n, field), o);
}

/// The fitted model with `normals` (exact normals from the field itself).
inline Model fieldModel(const std::string& field, int n, NormalMode normals) {
  const auto f = makeAnalyticField(field);
  BuildOptions o;
  o.isovalue = f->defaultIsovalue();
  o.normals = normals;
  o.exactField = f.get();
  return buildModel(sampleField(*f, n, field), o);
}

}  // namespace cip::test
