#include "common/models.hpp"
