// Every section of the run configuration in every test program that reads configs, as in
// src/cli/main.cpp (util/config_section.h: a section is registered by its header, and a program
// knows the sections of the headers it includes), so that each of them reads any config.toml.
#include "data/data_config.h"
#include "eval/eval_config.h"
#include "model/compute_config.h"
#include "model/model_config.h"
#include "train/train_config.h"
