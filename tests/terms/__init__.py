"""Terms and their inputs: effects, the user's terms and formulas, histories, the die temperature."""
