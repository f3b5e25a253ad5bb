#include "common/agent_core.hpp"
