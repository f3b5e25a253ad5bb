#include "common/target_core.hpp"
