#pragma once
// The session's value types moved to core/session.h (shared by every stage,
// not only the readers). This header stays so that code including it keeps
// compiling; new code includes core/session.h.
#include "core/session.h"
