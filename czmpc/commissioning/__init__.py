"""From a bare heater to a running MPC: the test, the check-model verdict, the journey."""
