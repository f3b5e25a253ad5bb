#include "common/simulation.hpp"
