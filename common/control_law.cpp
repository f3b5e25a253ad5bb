#include "common/control_law.hpp"
