#pragma once
// The ray-parallel CPU helpers live in the kernels library (kernels/cpu_parallel.h), below the
// model, because the packed CPU attention (kernels/packed_attention.h) uses them too. This header
// keeps the model's and the trainer's includes working.
#include "kernels/cpu_parallel.h"
