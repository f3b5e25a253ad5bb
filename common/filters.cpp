#include "common/filters.hpp"
