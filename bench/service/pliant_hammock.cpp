// SPDX-License-Identifier: Apache-2.0
// Water dropped into a cloth hammock, the two bodies stepped in turn and coupled as a server
// scene does: each step in the parts shared_step_parts gives (the fluid's 2 substeps and the
// cloth's 16: 2 parts), couple_particles_to_cloth after each part. How much of the water ends
// under the cloth, the cloth's push against the water's weight, and how much stayed in the
// hammock. docs/cloth.md, "Contact between bodies". One JSON line per configuration:
//   pliant_hammock [TICKS] [--one-part]   (default 600 ticks at 60 Hz; --one-part: the contact
//   once per step, after whole steps, as scenes stepped bodies before the parts)
// The hammock: a 0.6 m, 16 x 16 cloth pinned at its four corners at y = 0, damping 1/s, no
// self-collision; the water: cubes of 2, 3 and 5 particles a side 2 cm apart, 15 cm above the
// middle.
#include "pliant/cloth.hpp"
#include "pliant/coupling.hpp"
#include "pliant/fluid.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <string>

using namespace pliant;

namespace {

nlohmann::json run(double mass_per_area, int water_side, int ticks, bool one_part) {
  ClothGridSpec g;
  g.nx = g.ny = 16;
  g.size_x = g.size_y = 0.6;
  g.mass_per_area = mass_per_area;
  g.origin = Vec3(-0.3, 0.0, -0.3);
  ConstraintBodySettings cset;
  cset.damping = 1.0;
  cset.self_collision = false;
  auto cloth = ConstraintBody::cloth_grid(g, cset);
  for (size_t corner : {size_t(0), size_t(15), size_t(240), size_t(255)}) cloth->pin(corner);
  FluidSettings fs;
  fs.spacing = 0.02;
  const double half = 0.01 * water_side;  // water_side particles along each axis
  FluidBody water(fs, {FluidBlock{Vec3(-half, 0.15, -half), Vec3(half, 0.15 + 2 * half, half), Vec3::Zero()}});
  const double dt = 1.0 / 60;
  CouplingSettings contact;
  contact.radius = water.contact_radius() + cloth->contact_radius();
  contact.friction = 0.3;
  const int averaged = std::min(ticks, 120);
  const int substeps[] = {water.substeps(), cloth->substeps()};
  const int parts = one_part ? 1 : shared_step_parts(substeps);
  Vec3 push = Vec3::Zero();
  size_t most_under = 0;
  for (int k = 0; k < ticks; ++k) {
    const CouplingReport rep = step_with_cloth_contact(water, *cloth, contact, dt, {}, parts);
    const ParticleState &ws = water.state(), &cs = cloth->state();
    if (k >= ticks - averaged) push += rep.force_on_body / averaged;
    double lowest = 1e300;
    for (const Vec3& q : cs.x) lowest = std::min(lowest, q.y());
    size_t under = 0;
    for (const Vec3& p : ws.x) under += p.y() < lowest - 0.01 && std::abs(p.x()) < 0.25 && std::abs(p.z()) < 0.25;
    most_under = std::max(most_under, under);
  }
  double lowest = 1e300;
  for (const Vec3& q : cloth->state().x) lowest = std::min(lowest, q.y());
  size_t in_hammock = 0;
  for (const Vec3& p : water.state().x) in_hammock += p.y() > lowest - 0.05 && std::abs(p.x()) < 0.3 && std::abs(p.z()) < 0.3;
  const double weight = water.particle_mass() * double(water.size()) * 9.81;
  return {{"cloth_mass_per_area", mass_per_area},
          {"step_parts", parts},
          {"cloth_kg", cloth->total_mass()},
          {"water_particles", water.size()},
          {"water_kg", water.particle_mass() * double(water.size())},
          {"ticks", ticks},
          {"most_under_cloth", most_under},
          {"push_over_weight", -push.y() / weight},
          {"in_hammock_at_end", in_hammock}};
}

}  // namespace

int main(int argc, char** argv) {
  int ticks = 600;
  bool one_part = false;
  for (int a = 1; a < argc; ++a) {
    const std::string arg = argv[a];
    if (arg == "--one-part") {
      one_part = true;
    } else {
      ticks = std::atoi(arg.c_str());
      if (ticks < 1) {
        std::cerr << "pliant_hammock: TICKS must be >= 1, got '" << arg << "' (usage: pliant_hammock [TICKS] [--one-part])\n";
        return 2;
      }
    }
  }
  for (double mpa : {1.0, 0.2})
    for (int side : {2, 3, 5}) std::cout << run(mpa, side, ticks, one_part).dump() << std::endl;
  return 0;
}
