//! The rig controller: hardware-independent Controller plus the STM32 board binary (feature stm32).
