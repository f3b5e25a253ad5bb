#include "common/artefacts.hpp"
