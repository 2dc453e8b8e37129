// Placeholder: implemented by the stage's work.
