// The view settings as the server declares them (GET /api/settings): names,
// kinds, ranges, choices, units, defaults and docs. The client holds no
// defaults or ranges of its own: it builds its controls from this schema and
// sends values typed as the schema says (numbers as numbers, switches as
// booleans, choices and text forms as strings).

import { authFetch } from './auth.js';

export class Schema {
  // `description` is the JSON of GET /api/settings.
  constructor(description) {
    this.groups = description.groups;
    this.settings = new Map(description.settings.map((s) => [s.name, s]));
    // A slice view's own settings (w, h, cx, window, slab, …), alike.
    this.slice = description.slice ? new Schema(description.slice) : null;
  }

  static async load() {
    const response = await authFetch('/api/settings');
    if (!response.ok) throw new Error(`GET /api/settings answered ${response.status}`);
    return new Schema(await response.json());
  }

  // The setting `name`; throws for a name the server does not declare.
  get(name) {
    const setting = this.settings.get(name);
    if (!setting) throw new Error(`the server declares no view setting '${name}'`);
    return setting;
  }

  default(name) {
    return this.get(name).default;
  }

  // The settings of `group`, in the server's order.
  inGroup(group) {
    return [...this.settings.values()].filter((s) => s.group === group);
  }
}

// A value as a control shows it: a few significant digits.
function shown(setting, value) {
  if (typeof value !== 'number') return String(value);
  const text = setting.kind === 'number' ? String(Number(value.toPrecision(3))) : String(value);
  return setting.unit ? `${text} ${setting.unit}` : text;
}

// A labelled control for `setting`: a slider (numbers), a select (choices and
// one-of numbers), a checkbox (switches) or a colour input. `onInput(value)`
// runs with the typed value on every change. Returns the label element; its
// `value` getter and setter (on `label.setting`) read and write typed values.
export function control(setting, onInput) {
  const label = document.createElement('label');
  label.title = `${setting.doc} (${setting.expected})`;
  label.dataset.setting = setting.name;
  const name = setting.name.replaceAll('_', ' ');
  let input;
  let read;
  let write;
  const readout = document.createElement('output');
  switch (setting.kind) {
    case 'number':
    case 'whole': {
      input = document.createElement('input');
      input.type = 'range';
      input.min = setting.min;
      input.max = setting.max;
      input.step = setting.kind === 'whole' ? 1 : 'any';
      read = () => Number(input.value);
      write = (v) => { input.value = v; };
      break;
    }
    case 'one_of':
    case 'choice': {
      input = document.createElement('select');
      const options = setting.kind === 'choice'
        ? setting.choices.map((c) => ({ value: c.name, title: c.doc }))
        : setting.values.map((v) => ({ value: String(v), title: `${v} ${setting.unit}` }));
      for (const o of options) {
        const option = new Option(o.value, o.value);
        option.title = o.title;
        input.add(option);
      }
      read = () => (setting.kind === 'one_of' ? Number(input.value) : input.value);
      write = (v) => { input.value = String(v); };
      break;
    }
    case 'bool': {
      input = document.createElement('input');
      input.type = 'checkbox';
      read = () => input.checked;
      write = (v) => { input.checked = Boolean(v); };
      break;
    }
    case 'colour': {
      input = document.createElement('input');
      input.type = 'color';
      read = () => input.value.slice(1);
      write = (v) => { input.value = `#${v}`; };
      break;
    }
    default:
      throw new Error(`no control for the ${setting.kind} setting '${setting.name}'`);
  }
  input.id = `setting-${setting.name}`;
  const update = () => {
    readout.textContent = setting.kind === 'bool' ? '' : shown(setting, read());
  };
  if (setting.kind === 'bool') label.append(input, ` ${name}`);
  else label.append(`${name} `, input, ' ', readout);
  input.addEventListener('input', () => {
    update();
    onInput(read());
  });
  label.setting = {
    get value() { return read(); },
    set value(v) { write(v); update(); },
  };
  label.setting.value = setting.default;
  return label;
}
