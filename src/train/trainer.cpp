// Placeholder translation unit; the trainer lands here.
