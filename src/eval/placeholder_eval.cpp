// Module eval: see headers.
