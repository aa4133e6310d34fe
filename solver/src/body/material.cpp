// SPDX-License-Identifier: Apache-2.0
#include "pliant/material.hpp"

#include <cmath>
#include <sstream>

namespace pliant {

Lame lame_parameters(double E, double nu) {
  return {E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)), E / (2.0 * (1.0 + nu))};
}

Mat6 stvk_stiffness(const Lame& l) {
  Mat6 K = Mat6::Zero();
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) K(i, j) = l.lambda + (i == j ? 2.0 * l.mu : 0.0);
  for (int i = 3; i < 6; ++i) K(i, i) = l.mu;
  return K;
}

std::string_view to_string(ElasticModel m) {
  switch (m) {
    case ElasticModel::StVK: return "stvk";
    case ElasticModel::Corotated: return "corotated";
  }
  return "?";
}

std::optional<ElasticModel> parse_elastic_model(std::string_view s) {
  if (s == "stvk") return ElasticModel::StVK;
  if (s == "corotated") return ElasticModel::Corotated;
  return std::nullopt;
}

std::string validate(const Material& m) {
  std::ostringstream os;
  if (!std::isfinite(m.young) || m.young <= 0)
    os << "material.young must be a finite value > 0 Pa, got " << m.young;
  else if (!std::isfinite(m.poisson) || m.poisson <= -1.0 || m.poisson >= 0.5)
    os << "material.poisson must be in (-1, 0.5), got " << m.poisson;
  else if (!std::isfinite(m.density) || m.density <= 0)
    os << "material.density must be a finite value > 0 kg/m^3, got " << m.density;
  else if (!std::isfinite(m.inertia_floor) || m.inertia_floor < 0 || m.inertia_floor > 1)
    os << "material.inertia_floor must be in [0, 1] (a fraction of the mean vertex mass), got " << m.inertia_floor;
  else if (!std::isfinite(m.support_inertia) || m.support_inertia < 0 || m.support_inertia > 1)
    os << "material.support_inertia must be in [0, 1] (a fraction of the mass a vertex supports), got "
       << m.support_inertia;
  else if (m.model != ElasticModel::StVK && m.model != ElasticModel::Corotated)
    os << "material.model must be stvk or corotated, got " << int(m.model);
  return os.str();
}

}  // namespace pliant
