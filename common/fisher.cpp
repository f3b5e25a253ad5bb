#include "common/fisher.hpp"
