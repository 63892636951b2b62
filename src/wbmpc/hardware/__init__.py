"""The robot interface: Unitree SDK2 (CycloneDDS) LowState/LowCmd, a MuJoCo robot process behind
the same topics, the deploy controller and its safety layer. The SDK is imported only when used."""
