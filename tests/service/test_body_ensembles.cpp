// SPDX-License-Identifier: Apache-2.0
// Two chaotic server scenes run over a grid of nearby configurations: which configurations of a
// scene hold changes with the rounding of any part of the step (another compiler, the inversion
// floor's arithmetic), so one configuration passes or fails by luck; a grid tells what the
// product does (docs/fluids.md, "Cloths' and ropes' particles inside their substeps" and "The
// contact counted by both bodies' masses"). Label physics: about 40 s, not run under the
// sanitizers (test_bodies.cpp runs one configuration of each scene there).
#include "body_scenes.hpp"

#include <gtest/gtest.h>

#include <iostream>

using namespace pliant;

namespace {

using test::BodiesServer;

TEST(BodyEnsembles, ARopeUnderAFallingClothStaysWholeInMostNearbyScenes) {
  // A cloth falls onto a rope beside beam1's tip and wraps it (body_scenes.hpp); the rope and the
  // cloth touch each other along their links and edges. Whole: the rope's RMS stretch under 10%
  // on average over 5 s and under 500% at every tick. History: when a link's points were pushed
  // out of the cloth while its beads were in contact too, it exploded (43 times its length;
  // ClothContact.ALinkWhoseParticleTouchesIsLeftToItsParticles); a link crossed by the stretched
  // cloth sweeping past was thrown 11 cm across itself (502%;
  // ClothContact.ALinkANarrowFastStripSweptThroughIsNotThrownFartherThanItsLength). The one
  // configuration a test ran then held in the GCC build and, after the inversion floor took
  // det D_s det B, exploded in the sanitizers' Clang build (169 times its length). Over this grid
  // (the cloth 0.3 mm lower to 0.4 mm higher, the rope up to 0.2 mm aside) 8 of 40 exploded
  // (GCC), and 5 of 40 once the soft body met the cloth's triangles by both bodies' masses.
  // None since a point beside a sharp edge of the beam's surface reads outside: the cloth lies
  // along the beam's clamped end, and its particles there were thrown 5 mm a substep through the
  // end face (about 5 m/s), and the rope's contact with that agitated cloth exploded it. Asked: 36
  // of the 40 (the code before that fix: 35). Calm: the mean under 3% and no tick over 20%. While
  // the water's 2 substeps cut every pair's contacts to two a tick, 15 of the 40 were (the means
  // 2-8%, a tick up to 51%; with the water at 4 substeps none kept the mean under 10%); since each
  // pair meets as often as its own bodies' substeps allow (the rope and the cloth 16 times a
  // tick), all 40 are, the mean 1.8% in each (docs/data/pair_parts_grid.txt). Asked: 36.
  int whole = 0, calm = 0, runs = 0;
  for (double cloth_y : {0.0597, 0.0598, 0.0599, 0.06, 0.0601, 0.0602, 0.0603, 0.0604}) {
    for (double rope_z : {0.0073, 0.0074, 0.0075, 0.0076, 0.0077}) {
      BodiesServer srv;
      client::Client c = srv.client();
      const test::RopeRun run = test::run_rope_under_cloth(c, cloth_y, rope_z, 300, 5.0);
      const bool held = run.ticks == 300 && run.mean < 0.1 && run.worst < 5.0;
      std::cout << "[ wrap ] cloth at y " << cloth_y << " m, rope at z " << rope_z << " m: RMS stretch mean "
                << run.mean << ", largest " << run.worst << (held ? "" : " (exploded; stopped there)") << "\n";
      EXPECT_GT(run.contacts, 0u) << "the cloth reaches the rope";
      whole += held;
      calm += run.ticks == 300 && run.mean < 0.03 && run.worst < 0.2;
      ++runs;
    }
  }
  std::cout << "[ wrap ] " << whole << " of " << runs << " configurations keep the rope whole, " << calm
            << " calm\n";
  EXPECT_GE(whole, 36);
  EXPECT_GE(calm, 36);
}

TEST(BodyEnsembles, ASaggingBeamPressingOnAFineClothMostlyDoesNotBlowItUp) {
  // beam1 (clamped, 100 kPa) sags onto a 32 x 32 cloth of 12 cm held at its four corners 5 mm
  // under it (body_scenes.hpp). When the cloth met the beam only after its step, once per tick,
  // the beam pressed its particles in between and the contact threw them out: the cloth blew up
  // within 9 ticks (276 m/s, edges 58 times their length). Its particles now meet the beam's
  // surface inside their substeps, and the fabric is still under-resolved where the beam presses
  // (an edge reaches 2 to 6 times its length, which the log says). While the beam met the
  // cloth's triangles as fixed ones, its whole momentum went to the light particles under it
  // (kicks of 50 to 300 m/s a tick, 1e5 in a blow-up), and 16 of these 60 configurations (E
  // within 1%, heights within 0.4 mm) blew up within 30 ticks; meeting them by both bodies'
  // masses, none (the fastest particle 1.9 to 14 m/s); the beam then ended through the stretched
  // cloth in 4 of the 60. Since a cloth particle beside a sharp edge of the beam's surface reads
  // outside it (the surface's pseudo-normal; 0.09% of the pushes over this grid had read inside
  // and thrown the particle the radius through a face), in none, the fastest particle 1.8 to 2.3
  // m/s. Asked: 54 of the 60 under 20 m/s over 30 ticks, and at most 2 through the cloth.
  int survived = 0, through = 0, runs = 0;
  for (double young : {0.998e5, 0.999e5, 1e5, 1.001e5, 1.002e5, 1.01e5}) {
    for (double z : {-0.05475, -0.0548, -0.05485, -0.0549, -0.05495, -0.055, -0.05505, -0.0551, -0.05515, -0.0552}) {
      BodiesServer srv;
      client::Client c = srv.client();
      const test::SagRun run = test::run_sagging_beam_on_cloth(c, young, z, 30, 20.0);
      std::cout << "[ press ] E " << young << " Pa, cloth at z " << z << " m: the fastest particle " << run.fastest
                << " m/s" << (run.fastest > 20.0 ? " (stopped there)" : "") << (run.through ? ", the beam through the cloth" : "")
                << "\n";
      EXPECT_GT(run.touched, 0u) << "the beam reaches the cloth";
      survived += run.fastest < 20.0;
      through += run.through;
      ++runs;
    }
  }
  std::cout << "[ press ] " << survived << " of " << runs << " configurations under 20 m/s, the beam through the cloth in "
            << through << "\n";
  EXPECT_GE(10 * survived, 9 * runs);
  EXPECT_LE(through, 2) << "the beam ends through the cloth";
}

}  // namespace
