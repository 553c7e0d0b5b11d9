//! [`Field`]: a settings struct's field as a [`Setting`], and [`Nested`]: a
//! setting of a struct nested in another, as the outer struct's.

use std::fmt;
use std::marker::PhantomData;
use std::sync::OnceLock;

use super::values::expected_of;
use super::{Json, Raw, Setting, SettingError, SettingValue, Settings, Spec};

/// A field of type `T` of the settings struct `S`, as the
/// [`settings!`](crate::settings!) macro declares it.
pub struct Field<S, T> {
    /// What it is.
    pub spec: Spec,
    /// The field.
    pub get: fn(&S) -> &T,
    /// The field, to change.
    pub get_mut: fn(&mut S) -> &mut T,
    /// Its default.
    pub default: fn() -> T,
}

impl<S, T> fmt::Debug for Field<S, T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Field").field("spec", &self.spec).finish()
    }
}

impl<S, T: SettingValue> Setting<S> for Field<S, T> {
    fn spec(&self) -> &Spec {
        &self.spec
    }

    fn set(&self, settings: &mut S, raw: &Raw<'_>) -> Result<(), SettingError> {
        let value = T::read(raw, &self.spec.check)
            .map_err(|expected| SettingError::new(self.spec.name, raw, expected))?;
        *(self.get_mut)(settings) = value;
        Ok(())
    }

    fn reset(&self, settings: &mut S) {
        *(self.get_mut)(settings) = (self.default)();
    }

    fn validate(&self, settings: &S) -> Result<(), SettingError> {
        let value = (self.get)(settings);
        value
            .check(&self.spec.check)
            .map_err(|expected| SettingError::of_value(self.spec.name, value.to_json(), expected))
    }

    fn json(&self, settings: &S) -> Json {
        (self.get)(settings).to_json()
    }

    fn text(&self, settings: &S) -> String {
        (self.get)(settings).to_text()
    }

    fn default_json(&self) -> Json {
        (self.default)().to_json()
    }

    fn default_text(&self) -> String {
        (self.default)().to_text()
    }

    fn kind(&self) -> &'static str {
        T::kind(&self.spec.check)
    }

    fn expected(&self) -> String {
        expected_of::<T>(&self.spec.check).0
    }

    fn choices(&self) -> Vec<(&'static str, &'static str)> {
        T::choices()
    }
}

/// A setting of the settings struct `I` nested in `O` (the camera in the
/// frame request): the inner setting through the outer struct's field.
pub struct Nested<O: 'static, I: 'static> {
    inner: &'static dyn Setting<I>,
    get: fn(&O) -> &I,
    get_mut: fn(&mut O) -> &mut I,
    _outer: PhantomData<fn(&O)>,
}

impl<O: 'static, I: 'static> fmt::Debug for Nested<O, I> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Nested")
            .field("spec", self.inner.spec())
            .finish()
    }
}

impl<O: 'static, I: 'static> Nested<O, I> {
    /// `inner`, reached through `get` and `get_mut`.
    pub fn new(
        inner: &'static dyn Setting<I>,
        get: fn(&O) -> &I,
        get_mut: fn(&mut O) -> &mut I,
    ) -> Nested<O, I> {
        Nested {
            inner,
            get,
            get_mut,
            _outer: PhantomData,
        }
    }
}

impl<O: 'static, I: 'static> Setting<O> for Nested<O, I> {
    fn spec(&self) -> &Spec {
        self.inner.spec()
    }

    fn set(&self, settings: &mut O, raw: &Raw<'_>) -> Result<(), SettingError> {
        self.inner.set((self.get_mut)(settings), raw)
    }

    fn reset(&self, settings: &mut O) {
        self.inner.reset((self.get_mut)(settings));
    }

    fn validate(&self, settings: &O) -> Result<(), SettingError> {
        self.inner.validate((self.get)(settings))
    }

    fn json(&self, settings: &O) -> Json {
        self.inner.json((self.get)(settings))
    }

    fn text(&self, settings: &O) -> String {
        self.inner.text((self.get)(settings))
    }

    fn default_json(&self) -> Json {
        self.inner.default_json()
    }

    fn default_text(&self) -> String {
        self.inner.default_text()
    }

    fn kind(&self) -> &'static str {
        self.inner.kind()
    }

    fn expected(&self) -> String {
        self.inner.expected()
    }

    fn choices(&self) -> Vec<(&'static str, &'static str)> {
        self.inner.choices()
    }
}

/// Lists the settings of `O`'s nested struct `I` as settings of `O` (the
/// [`settings!`](crate::settings!) macro's `groups` section).
pub fn nest<O: Settings, I: Settings>(
    get: fn(&O) -> &I,
    get_mut: fn(&mut O) -> &mut I,
) -> impl Iterator<Item = &'static dyn Setting<O>> {
    I::settings().iter().map(move |inner| {
        let nested: &'static dyn Setting<O> =
            Box::leak(Box::new(Nested::new(*inner, get, get_mut)));
        nested
    })
}

/// Builds a struct's setting list once (the [`settings!`](crate::settings!)
/// macro's [`Settings::settings`]).
pub fn once<S: 'static>(
    cell: &'static OnceLock<Vec<&'static dyn Setting<S>>>,
    build: impl FnOnce() -> Vec<&'static dyn Setting<S>>,
) -> &'static [&'static dyn Setting<S>] {
    cell.get_or_init(build)
}
