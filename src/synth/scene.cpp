// Placeholder translation unit; the demo-scene renderer lands here.
