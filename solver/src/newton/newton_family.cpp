#include "step/family.hpp"

#include <stdexcept>

namespace pliant::detail {

// Placeholder until the family lands: validate() refuses the method first.
std::unique_ptr<SolverFamily> make_newton_family() {
  throw std::logic_error("solver.method newton is not available in this build");
}

}  // namespace pliant::detail
